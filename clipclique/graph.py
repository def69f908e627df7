"""Semantic graph of ellipsoid centres and the two graph descriptors built on it.

- Semantic graph: nodes are objects, an edge joins two objects whose centres are closer than
  `d_adj` (no self-loops). Stored as a boolean scipy CSR matrix.
- Semantic Histogram (Guo et al., as CLIP-Clique uses it): for node v, enumerate every walk of
  `s` nodes that starts at v, `v = u_1 - u_2 - ... - u_s`, each step to any graph neighbour, so
  a walk may step straight back (`v - n - v` is a walk of 3). Each walk's class-label sequence
  `(c(u_1), ..., c(u_s))` is one of `C^s` bins (bin = base-C number of the labels, first label
  most significant); the histogram counts walks per bin and is L2-normalized. A node with no
  neighbour has no walk of s > 1 nodes: its histogram is all zeros (similarity 0 to everything;
  `similarity.class_weight` gives such a node its class as evidence, see `similarity`).
  Histograms are sparse rows of an (N, C^s) CSR matrix: NYU40 has 64,000 bins per node.
- X-View random-walk descriptor (Gawel et al., baseline): for node v, `walks` random walks of
  `s` nodes starting at v, each step to a uniformly drawn neighbour (an isolated node stays on
  itself); the descriptor is the count of each label sequence, as a sparse (N, C^s) row.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree


def semantic_graph(centers: np.ndarray, d_adj: float) -> sp.csr_matrix:
    """(N, N) boolean adjacency: True where two distinct centres are closer than `d_adj`."""
    n = len(centers)
    if n == 0:
        return sp.csr_matrix((0, 0), dtype=bool)
    pairs = cKDTree(centers).query_pairs(d_adj, output_type="ndarray")
    distances = np.linalg.norm(centers[pairs[:, 0]] - centers[pairs[:, 1]], axis=1)
    pairs = pairs[distances < d_adj]  # query_pairs includes distance == d_adj; the rule is strict
    rows = np.concatenate((pairs[:, 0], pairs[:, 1]))
    cols = np.concatenate((pairs[:, 1], pairs[:, 0]))
    return sp.csr_matrix((np.ones(len(rows), dtype=bool), (rows, cols)), shape=(n, n))


def semantic_histograms(
    adjacency: sp.csr_matrix,
    class_ids: np.ndarray,
    num_classes: int,
    walk_length: int = 3,
    kernel: sp.csr_matrix | None = None,
) -> sp.csr_matrix:
    """(N, C^s) L2-normalized Semantic Histograms: every walk of `walk_length` nodes from each node.

    With a class `kernel` (C, C) (`clipclique.lookalikes`), each node's label is soft: a walk
    counts `prod_i kernel[c(u_i), k_i]` in every bin `(k_1, ..., k_s)`, so a walk through a node
    the detector may have mislabelled (a "bottle" that is a cup) also counts where the true label
    would have put it. Without a kernel the counts are the exact-label ones.
    """
    n = adjacency.shape[0]
    class_ids = np.asarray(class_ids, dtype=np.int64)
    starts = np.arange(n)
    ends = starts
    walk, codes, weights = _labels(class_ids[ends], kernel)
    starts, ends = starts[walk], ends[walk]
    for _ in range(walk_length - 1):
        step, ends = _expand(adjacency, ends)
        starts, codes, weights = starts[step], codes[step], weights[step]
        walk, labels, label_weights = _labels(class_ids[ends], kernel)
        starts, ends = starts[walk], ends[walk]
        codes, weights = codes[walk] * num_classes + labels, weights[walk] * label_weights
    return _l2_normalized(_count_matrix(starts, codes, n, num_classes**walk_length, weights))


def random_walk_descriptors(
    adjacency: sp.csr_matrix,
    class_ids: np.ndarray,
    num_classes: int,
    walk_length: int,
    walks: int,
    rng: np.random.Generator,
) -> sp.csr_matrix:
    """(N, C^s) counts of the label sequences of `walks` random walks of `walk_length` nodes per node."""
    n = adjacency.shape[0]
    starts = np.repeat(np.arange(n), walks)
    ends = starts
    class_ids = np.asarray(class_ids, dtype=np.int64)
    codes = class_ids[starts]
    degree = np.diff(adjacency.indptr)
    for _ in range(walk_length - 1):
        pick = (rng.random(len(ends)) * degree[ends]).astype(np.int64)
        moving = np.flatnonzero(degree[ends] > 0)
        ends = ends.copy()
        ends[moving] = adjacency.indices[adjacency.indptr[ends[moving]] + pick[moving]]
        codes = codes * num_classes + class_ids[ends]
    return _count_matrix(starts, codes, n, num_classes**walk_length)


def _expand(adjacency: sp.csr_matrix, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every one-step extension of walks ending at `nodes`: (index of the walk extended, new end)."""
    degree = np.diff(adjacency.indptr)[nodes]
    walk = np.repeat(np.arange(len(nodes)), degree)
    first = np.cumsum(degree) - degree
    offset = np.arange(len(walk)) - np.repeat(first, degree)
    return walk, adjacency.indices[np.repeat(adjacency.indptr[nodes], degree) + offset]


def _labels(classes: np.ndarray, kernel: sp.csr_matrix | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The soft labels of nodes of the given `classes`: (index of the node, label, weight) per alternative."""
    if kernel is None:
        return np.arange(len(classes)), classes, np.ones(len(classes))
    count = np.diff(kernel.indptr)[classes]
    node = np.repeat(np.arange(len(classes)), count)
    offset = np.arange(len(node)) - np.repeat(np.cumsum(count) - count, count)
    entry = np.repeat(kernel.indptr[classes], count) + offset
    return node, kernel.indices[entry].astype(np.int64), kernel.data[entry]


def _count_matrix(
    rows: np.ndarray, codes: np.ndarray, n: int, bins: int, weights: np.ndarray | None = None
) -> sp.csr_matrix:
    counts = sp.csr_matrix((np.ones(len(rows)) if weights is None else weights, (rows, codes)), shape=(n, bins))
    counts.sum_duplicates()
    return counts


def _l2_normalized(matrix: sp.csr_matrix) -> sp.csr_matrix:
    norms = np.sqrt(np.asarray(matrix.multiply(matrix).sum(axis=1)).ravel())
    return sp.csr_matrix(sp.diags(np.where(norms > 0, 1.0 / np.maximum(norms, 1e-300), 0.0)) @ matrix)
