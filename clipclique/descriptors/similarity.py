"""Observation-by-landmark similarity matrices, (K, N): CLIP, Semantic Histogram, X-View, fused."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit

from clipclique.descriptors.graph import SparseRows

# observations: up to here the compiled dot products replace BLAS's product (beyond, BLAS's sums: with 24 here, two
# golden desk frames of more than 16 observations reached one maximal clique more or fewer, a last-bit tie)
COMPILED_ROWS_UP_TO = 16
BLOCK = 4  # image rows `_dot_products` takes through the text at once


def clip_similarity(image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
    """Cosine similarity of L2-normalized CLIP image (K, D) and text (N, D) embeddings, in float64.

    Up to COMPILED_ROWS_UP_TO observations by compiled dot products (`_dot_products`): BLAS's product of a frame's
    (K, 512) by (512, N) took 10 to 27 us, two to three times theirs. Only the order of each sum differs (BLAS has
    its own), by a few 1e-17."""
    image = np.asarray(image_embeddings)
    if len(image) > COMPILED_ROWS_UP_TO or image.dtype not in (np.float32, np.float64):
        return np.asarray(image, np.float64) @ np.asarray(text_embeddings, np.float64).T
    return _dot_products(image, np.asarray(text_embeddings, np.float64))


@njit(cache=True, fastmath={"reassoc", "contract", "nsz"})
def _dot_products(image: np.ndarray, text: np.ndarray) -> np.ndarray:
    """(K, N) each image row's float64 dot product with each text row: BLOCK image rows at a time (as float64, in L1
    cache) against each text row, read once a block, in four independent sums. A product of float32 embeddings is exact
    in float64, so reassociating the sums (vectorized) and contracting into FMAs move only the sums' last bits."""
    rows, width = image.shape
    out = np.empty((rows, text.shape[0]))
    block = np.zeros((BLOCK, width))  # rows past the last stay 0: their sums are dropped
    for first in range(0, rows, BLOCK):
        taken = min(BLOCK, rows - first)
        for r in range(taken):
            for d in range(width):
                block[r, d] = image[first + r, d]
        for r in range(taken, BLOCK):
            block[r, :] = 0.0
        for j in range(text.shape[0]):
            s0 = s1 = s2 = s3 = 0.0
            for d in range(width):
                value = text[j, d]
                s0 += block[0, d] * value
                s1 += block[1, d] * value
                s2 += block[2, d] * value
                s3 += block[3, d] * value
            sums = (s0, s1, s2, s3)
            for r in range(taken):
                out[first + r, j] = sums[r]
    return out


def histogram_similarity(query: sp.csr_matrix | SparseRows, landmarks_by_bin: sp.csr_matrix) -> np.ndarray:
    """Dot products of L2-normalized Semantic Histograms, i.e. their cosine similarity in [0, 1]; `query` (K, C^s)
    a CSR matrix or its rows (`graph.query_histograms`).

    `landmarks_by_bin` is the map's (N, C^s) histograms transposed to a (C^s, N) CSR matrix
    (`by_bin`), made once per map: `query @ landmarks.T` would convert it again every query. The
    product is `(query @ landmarks_by_bin).toarray()` (each sum from 0, its terms in the query row's stored
    order, as scipy's sparse product adds them), written straight into the
    dense result instead of through a sparse one."""
    out = np.zeros((query.shape[0], landmarks_by_bin.shape[1]))
    _sparse_product_into(out, query.indptr, query.indices, query.data.astype(np.float64, copy=False),
                         landmarks_by_bin.indptr, landmarks_by_bin.indices,
                         landmarks_by_bin.data.astype(np.float64, copy=False))
    return out


@njit(cache=True)
def _sparse_product_into(out: np.ndarray, pointers: np.ndarray, columns: np.ndarray, values: np.ndarray,
                         other_pointers: np.ndarray, other_columns: np.ndarray, other_values: np.ndarray) -> None:
    for i in range(len(pointers) - 1):
        row = out[i]
        for e in range(pointers[i], pointers[i + 1]):
            b, value = columns[e], values[e]
            for f in range(other_pointers[b], other_pointers[b + 1]):
                product = value * other_values[f]  # rounded apart from the sum, as scipy's loop does
                row[other_columns[f]] += product


def by_bin(landmarks: sp.csr_matrix) -> sp.csr_matrix:
    """(C^s, N) the histograms transposed, as the CSR matrix scipy converts `landmarks.T` to in a product."""
    return landmarks.T.tocsr()


def walk_similarity(query_counts: sp.csr_matrix, landmark_counts: sp.csr_matrix) -> np.ndarray:
    """X-View's score: the fraction of the observation's random walks whose label sequence
    also occurs among the landmark's walks (in [0, 1]; a walk counts with its multiplicity)."""
    present = landmark_counts.copy()
    present.data[:] = 1.0
    walks = np.asarray(query_counts.sum(axis=1)).ravel()
    return (query_counts @ present.T).toarray() / np.maximum(walks, 1.0)[:, None]


def kernel_columns(kernel: sp.csr_matrix, landmark_classes: np.ndarray) -> np.ndarray:
    """(C, N) dense, C-ordered (a row per query class, read along): the kernel between every class and each
    landmark's class."""
    return np.ascontiguousarray(kernel.toarray()[:, landmark_classes])


def soft_class_similarity(query_classes: np.ndarray, kernel: sp.csr_matrix, distributions: sp.csr_matrix) -> np.ndarray:
    """(K, N) the class kernel's expectation over each landmark's class `distributions` (N, C): the
    class term of a map that says how sure it is of each landmark's class (similarity.soft_classes)."""
    return (kernel[query_classes] @ distributions.T).toarray()


def with_class_term(histogram: np.ndarray, classes: np.ndarray, rows: np.ndarray, weight: float) -> np.ndarray:
    """`weight * S_class + (1 - weight) * S_sh`, S_class = `classes[rows]`, written over `histogram` (K, N) and
    returned: an object with no neighbour within d_adj has an empty Semantic Histogram, so without the class term it
    matches nothing; with it a lone chair still matches the map's chairs (and, more weakly, its look-alikes).

    `classes` is the (C, N) kernel between every class and each landmark's class (`kernel_columns`, made once
    per map) with `rows` the observations' classes, or a (K, N) class term (`soft_class_similarity`) with `rows`
    0..K-1. One compiled pass instead of a gather and three (K, N) temporaries, numpy's operations in numpy's
    order: (weight * class) + ((1 - weight) * histogram)."""
    _with_class_term_into(histogram, np.ascontiguousarray(classes, np.float64), np.asarray(rows, np.int64),
                          float(weight))
    return histogram


@njit(cache=True)
def _with_class_term_into(histogram: np.ndarray, classes: np.ndarray, rows: np.ndarray, weight: float) -> None:
    rest = 1.0 - weight
    for i in range(histogram.shape[0]):
        row = classes[rows[i]]
        for j in range(histogram.shape[1]):
            histogram[i, j] = weight * row[j] + rest * histogram[i, j]


def fuse(clip: np.ndarray, histogram: np.ndarray, alpha: float) -> np.ndarray:
    """S = alpha * S_clip + (1 - alpha) * S_sh, written over `clip` (K, N) float64 and returned: numpy's operations in
    numpy's order, (alpha * clip) + ((1 - alpha) * histogram), in one compiled pass instead of three (K, N)
    temporaries."""
    _fuse_into(clip, np.asarray(histogram, np.float64), float(alpha))
    return clip


@njit(cache=True)
def _fuse_into(clip: np.ndarray, histogram: np.ndarray, alpha: float) -> None:
    rest = 1.0 - alpha
    for i in range(clip.shape[0]):
        for j in range(clip.shape[1]):
            clip[i, j] = alpha * clip[i, j] + rest * histogram[i, j]

