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


def semantic_graph(centers: np.ndarray, d_adj: float, max_degree: int | None = None) -> sp.csr_matrix:
    """(N, N) boolean adjacency: True where two distinct centres are closer than `d_adj`.

    With `max_degree`, each node keeps at most its `max_degree` nearest neighbours and an edge
    stays only where both ends keep it, so memory is bounded by N * max_degree whatever the map
    (5,000 landmarks piled in one spot would otherwise ask for 25 million edges). Real scenes stay
    far below it (a cluttered desk: degree 30 at most); `capped_nodes` says when it bit.
    """
    n = len(centers)
    if n == 0:
        return sp.csr_matrix((0, 0), dtype=bool)
    tree = cKDTree(centers)
    if max_degree is None:
        pairs = tree.query_pairs(d_adj, output_type="ndarray")
        distances = np.linalg.norm(centers[pairs[:, 0]] - centers[pairs[:, 1]], axis=1)
        pairs = pairs[distances < d_adj]  # query_pairs includes distance == d_adj; the rule is strict
        rows = np.concatenate((pairs[:, 0], pairs[:, 1]))
        cols = np.concatenate((pairs[:, 1], pairs[:, 0]))
        return sp.csr_matrix((np.ones(len(rows), dtype=bool), (rows, cols)), shape=(n, n))
    k = min(max_degree + 1, n)  # + 1: the node itself comes back too
    distances, neighbours = tree.query(centers, k=k, distance_upper_bound=d_adj)
    distances, neighbours = distances.reshape(n, k), neighbours.reshape(n, k)
    rows = np.repeat(np.arange(n), k)
    keep = (distances.ravel() < d_adj) & (neighbours.ravel() != rows)
    kept = sp.csr_matrix((np.ones(keep.sum(), dtype=bool), (rows[keep], neighbours.ravel()[keep])), shape=(n, n))
    return kept.multiply(kept.T).tocsr().astype(bool)  # mutual: both ends kept the edge


def capped_nodes(centers: np.ndarray, d_adj: float, adjacency: sp.csr_matrix) -> int:
    """How many nodes lost neighbours to `max_degree` (0 when the cap did not bite)."""
    full = cKDTree(centers).query_ball_point(centers, d_adj, return_length=True) - 1  # less the node itself
    return int(np.count_nonzero(full > np.diff(adjacency.indptr)))


def semantic_histograms(
    adjacency: sp.csr_matrix,
    class_ids: np.ndarray,
    num_classes: int,
    walk_length: int = 3,
    kernel: sp.csr_matrix | None = None,
    distributions: sp.csr_matrix | None = None,
) -> sp.csr_matrix:
    """(N, C^s) L2-normalized Semantic Histograms: every walk of `walk_length` nodes from each node.

    Computed without listing walks (a node of degree d has d^(s-1) of them): with H_1 the label
    rows, the walks of k + 1 nodes from v are v's label followed by the walks of k nodes from each
    neighbour, `H_{k+1}[v] = label(v) (x) sum_u A[v, u] H_k[u]` (a row-wise Kronecker product),
    so the cost grows with the distinct bins, not with the walks.

    With a class `kernel` (C, C) (`clipclique.lookalikes`), each node's label is soft: a walk
    counts `prod_i kernel[c(u_i), k_i]` in every bin `(k_1, ..., k_s)`, so a walk through a node
    the detector may have mislabelled (a "bottle" that is a cup) also counts where the true label
    would have put it. Without a kernel the counts are the exact-label ones. With `distributions`
    (N, C), each node's label row is its own class distribution (a map unsure of its classes).
    """
    n = adjacency.shape[0]
    labels = (sp.csr_matrix(distributions) if distributions is not None
              else _label_rows(np.asarray(class_ids, dtype=np.int64), num_classes, kernel))
    steps = sp.csr_matrix(adjacency, dtype=np.float64)
    walks = labels
    for _ in range(walk_length - 1):
        walks = _prefixed(labels, (steps @ walks).tocsr())
    walks.sum_duplicates()
    walks.eliminate_zeros()
    return _l2_normalized(walks) if n else walks


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


def _label_rows(class_ids: np.ndarray, num_classes: int, kernel: sp.csr_matrix | None) -> sp.csr_matrix:
    """(N, C): each node's label as a one-hot row, or its class's kernel row (soft labels)."""
    one_hot = sp.csr_matrix((np.ones(len(class_ids)), (np.arange(len(class_ids)), class_ids)),
                            shape=(len(class_ids), num_classes))
    return one_hot if kernel is None else (one_hot @ kernel).tocsr()


def _prefixed(labels: sp.csr_matrix, tails: sp.csr_matrix) -> sp.csr_matrix:
    """Row-wise Kronecker product: out[v, c * B + j] = labels[v, c] * tails[v, j], B = tails' width."""
    width = tails.shape[1]
    label_count, tail_count = np.diff(labels.indptr), np.diff(tails.indptr)
    count = label_count * tail_count
    rows = np.repeat(np.arange(labels.shape[0]), count)
    position = np.arange(len(rows)) - np.repeat(np.cumsum(count) - count, count)
    per_label = np.repeat(tail_count, count)
    label_entry = labels.indptr[rows] + position // np.maximum(per_label, 1)
    tail_entry = tails.indptr[rows] + position % np.maximum(per_label, 1)
    columns = labels.indices[label_entry].astype(np.int64) * width + tails.indices[tail_entry]
    return sp.csr_matrix((labels.data[label_entry] * tails.data[tail_entry], (rows, columns)),
                         shape=(labels.shape[0], labels.shape[1] * width))


def _count_matrix(rows: np.ndarray, codes: np.ndarray, n: int, bins: int) -> sp.csr_matrix:
    counts = sp.csr_matrix((np.ones(len(rows)), (rows, codes)), shape=(n, bins))
    counts.sum_duplicates()
    return counts


def _l2_normalized(matrix: sp.csr_matrix) -> sp.csr_matrix:
    norms = np.sqrt(np.asarray(matrix.multiply(matrix).sum(axis=1)).ravel())
    return sp.csr_matrix(sp.diags(np.where(norms > 0, 1.0 / np.maximum(norms, 1e-300), 0.0)) @ matrix)
