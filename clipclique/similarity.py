"""Observation-by-landmark similarity matrices, (K, N): CLIP, Semantic Histogram, X-View, fused."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def clip_similarity(image_embeddings: np.ndarray, text_embeddings: np.ndarray) -> np.ndarray:
    """Cosine similarity of L2-normalized CLIP image (K, D) and text (N, D) embeddings."""
    return np.asarray(image_embeddings, np.float64) @ np.asarray(text_embeddings, np.float64).T


def histogram_similarity(query: sp.csr_matrix, landmarks: sp.csr_matrix) -> np.ndarray:
    """Dot products of L2-normalized Semantic Histograms, i.e. their cosine similarity in [0, 1]."""
    return (query @ landmarks.T).toarray()


def walk_similarity(query_counts: sp.csr_matrix, landmark_counts: sp.csr_matrix) -> np.ndarray:
    """X-View's score: the fraction of the observation's random walks whose label sequence
    also occurs among the landmark's walks (in [0, 1]; a walk counts with its multiplicity)."""
    present = landmark_counts.copy()
    present.data[:] = 1.0
    walks = np.asarray(query_counts.sum(axis=1)).ravel()
    return (query_counts @ present.T).toarray() / np.maximum(walks, 1.0)[:, None]


def class_similarity(query_classes: np.ndarray, landmark_classes: np.ndarray, kernel: sp.csr_matrix,
                     distributions: sp.csr_matrix | None = None) -> np.ndarray:
    """(K, N) the class kernel between each observation's class and each landmark's: 1 for the same
    class, the look-alike weight for classes a detector confuses, 0 otherwise. With the landmarks'
    class `distributions` (N, C), its expectation over each landmark's classes instead."""
    if distributions is not None:
        return (kernel[query_classes] @ distributions.T).toarray()
    return kernel[query_classes][:, landmark_classes].toarray()


def with_class_term(histogram: np.ndarray, classes: np.ndarray, weight: float) -> np.ndarray:
    """`weight * S_class + (1 - weight) * S_sh`: an object with no neighbour within d_adj has an
    empty Semantic Histogram, so without the class term it matches nothing; with it a lone chair
    still matches the map's chairs (and, more weakly, its look-alikes)."""
    return weight * classes + (1.0 - weight) * histogram


def fuse(clip: np.ndarray, histogram: np.ndarray, alpha: float) -> np.ndarray:
    """S = alpha * S_clip + (1 - alpha) * S_sh."""
    return alpha * clip + (1.0 - alpha) * histogram
