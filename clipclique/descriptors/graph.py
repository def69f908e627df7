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

import math
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.spatial import cKDTree


def semantic_graph(centers: np.ndarray, d_adj: float, max_degree: int | None = None) -> sp.csr_matrix:
    """(N, N) boolean adjacency: True where two distinct centres are closer than `d_adj`.

    With `max_degree`, each node keeps at most its `max_degree` nearest neighbours and an edge
    stays only where both ends keep it, so memory is bounded by N * max_degree whatever the map
    (5,000 landmarks piled in one spot would otherwise ask for 25 million edges). Real scenes stay
    far below it (a cluttered desk: degree 30 at most); `capped_semantic_graph` says when it bit.
    """
    n = len(centers)
    if n == 0:
        return sp.csr_matrix((0, 0), dtype=bool)
    if max_degree is not None:
        return capped_semantic_graph(centers, d_adj, max_degree).adjacency
    tree = cKDTree(centers)
    pairs = tree.query_pairs(d_adj, output_type="ndarray")
    distances = np.linalg.norm(centers[pairs[:, 0]] - centers[pairs[:, 1]], axis=1)
    pairs = pairs[distances < d_adj]  # query_pairs includes distance == d_adj; the rule is strict
    rows = np.concatenate((pairs[:, 0], pairs[:, 1]))
    cols = np.concatenate((pairs[:, 1], pairs[:, 0]))
    return sp.csr_matrix((np.ones(len(rows), dtype=bool), (rows, cols)), shape=(n, n))


class CappedGraph(NamedTuple):
    """`semantic_graph(centers, d_adj, max_degree)` and how many nodes lost neighbours to the cap."""

    adjacency: sp.csr_matrix  # (N, N) boolean
    capped_nodes: int  # nodes with more centres within d_adj (distance == d_adj included) than edges; 0: none
    tree: cKDTree  # the centres' KD-tree it was built with, for whatever else asks which centres are near


def capped_semantic_graph(centers: np.ndarray, d_adj: float, max_degree: int) -> CappedGraph:
    """The degree-capped semantic graph with its count of capped nodes, from one pair query.

    Defined as it was built before: each node's `max_degree` + 1 nearest centres from cKDTree's k-nearest query
    bounded by `d_adj` (itself among them), less itself and any at a returned distance not below `d_adj`, an edge
    where both ends keep it; a node is capped where `query_ball_point` (distance <= d_adj) counts more centres
    than it has edges. cKDTree's pair query counts what the ball query counts (squared distance
    `(dx*dx + dy*dy) + dz*dz <= d_adj*d_adj`), and a node with at most `max_degree` of them gets every centre
    the k-nearest query would accept (squared distance < d_adj*d_adj) back from it: only the nodes with more
    (none on a real map) go to the k-nearest query, which took 70 ms on a map of 47,000 landmarks, and the ball
    query (60 ms) is not needed at all.
    """
    n = len(centers)
    centers = np.asarray(centers, dtype=np.float64)
    tree = cKDTree(centers)
    if n == 0:
        return CappedGraph(sp.csr_matrix((0, 0), dtype=bool), 0, tree)
    pairs = tree.query_pairs(d_adj, output_type="ndarray")
    within = np.bincount(pairs.ravel(), minlength=n)  # centres at distance <= d_adj, less the node itself
    k = min(max_degree + 1, n)  # + 1: the node itself comes back too
    full = np.flatnonzero(within + 1 > k)
    distances, neighbours = tree.query(centers[full], k=k, distance_upper_bound=d_adj)
    pointers, indices = _capped_rows(np.ascontiguousarray(centers), float(d_adj), pairs.astype(np.int64, copy=False),
                                     full.astype(np.int64), distances.reshape(len(full), k),
                                     neighbours.reshape(len(full), k).astype(np.int64, copy=False))
    adjacency = sp.csr_matrix((np.ones(len(indices), dtype=bool), indices, pointers), shape=(n, n))
    return CappedGraph(adjacency, int(np.count_nonzero(within > np.diff(pointers))), tree)


@njit(cache=True)
def _capped_rows(centers: np.ndarray, d_adj: float, pairs: np.ndarray, full: np.ndarray, distances: np.ndarray,
                 neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR rows (pointers, ascending indices) of the capped graph: each node's kept centres (the `pairs` closer
    than `d_adj` as the k-nearest query measures them, or for a `full` node its k-nearest query's `distances` and
    `neighbours`), then only the edges both ends kept."""
    n = len(centers)
    is_full = np.zeros(n, np.bool_)
    is_full[full] = True
    limit = d_adj * d_adj
    close = np.zeros(len(pairs), np.bool_)
    kept_pointers = np.zeros(n + 1, np.int64)
    for p in range(len(pairs)):
        i, j = pairs[p, 0], pairs[p, 1]
        dx, dy, dz = centers[i, 0] - centers[j, 0], centers[i, 1] - centers[j, 1], centers[i, 2] - centers[j, 2]
        squared = (dx * dx + dy * dy) + dz * dz  # cKDTree's sum, in its order
        if squared < limit and math.sqrt(squared) < d_adj:
            close[p] = True
            kept_pointers[i + 1] += not is_full[i]
            kept_pointers[j + 1] += not is_full[j]
    for f in range(len(full)):
        for t in range(neighbours.shape[1]):
            kept_pointers[full[f] + 1] += neighbours[f, t] != full[f] and distances[f, t] < d_adj
    for v in range(n):
        kept_pointers[v + 1] += kept_pointers[v]
    kept = np.empty(kept_pointers[n], np.int64)
    at = kept_pointers[:n].copy()
    for p in range(len(pairs)):
        if close[p]:
            i, j = pairs[p, 0], pairs[p, 1]
            if not is_full[i]:
                kept[at[i]] = j
                at[i] += 1
            if not is_full[j]:
                kept[at[j]] = i
                at[j] += 1
    for f in range(len(full)):
        v = full[f]
        for t in range(neighbours.shape[1]):
            if neighbours[f, t] != v and distances[f, t] < d_adj:
                kept[at[v]] = neighbours[f, t]
                at[v] += 1
    if len(full) == 0:  # every node kept all its neighbours: the kept rows are mutual, their transpose sorted
        return _transpose(kept_pointers, kept)
    kept_pointers, kept = _transpose(*_transpose(kept_pointers, kept))
    pointers = np.zeros(n + 1, np.int64)
    indices = np.empty(len(kept), np.int64)
    for v in range(n):
        at_v = pointers[v]
        for e in range(kept_pointers[v], kept_pointers[v + 1]):
            u = kept[e]
            if _holds(kept, kept_pointers[u], kept_pointers[u + 1], v):
                indices[at_v] = u
                at_v += 1
        pointers[v + 1] = at_v
    return pointers, indices[:pointers[n]]


@njit(cache=True)
def _transpose(pointers: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The transpose of a square pattern's CSR rows, each row's indices ascending (a counting sort: rows are read
    in order, so each column collects them ascending)."""
    n = len(pointers) - 1
    out_pointers = np.zeros(n + 1, np.int64)
    for e in range(len(indices)):
        out_pointers[indices[e] + 1] += 1
    for v in range(n):
        out_pointers[v + 1] += out_pointers[v]
    out = np.empty(len(indices), np.int64)
    at = out_pointers[:n].copy()
    for v in range(n):
        for e in range(pointers[v], pointers[v + 1]):
            u = indices[e]
            out[at[u]] = v
            at[u] += 1
    return out_pointers, out


@njit(cache=True)
def _holds(sorted_values: np.ndarray, start: int, end: int, value: int) -> bool:
    """Whether sorted_values[start:end] (ascending) holds `value` (a binary search)."""
    low, high = start, end
    while low < high:
        middle = (low + high) // 2
        if sorted_values[middle] < value:
            low = middle + 1
        else:
            high = middle
    return low < end and sorted_values[low] == value


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

    With a class `kernel` (C, C) (`clipclique.descriptors.lookalikes`), each node's label is soft: a walk
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
        walks = _row_kron(labels, (steps @ walks).tocsr())
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


def _row_kron(labels: sp.csr_matrix, tails: sp.csr_matrix) -> sp.csr_matrix:
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


SORTED_IN_PLACE_UP_TO = 32  # a row's tails: up to here sorted by insertion (`sort_span`), beyond by numpy's sort
QUERY_BINS_LIMIT = 1 << 22  # widest walk prefix (C^(s-1) bins) the compiled query path accumulates densely


class SparseRows(NamedTuple):
    """CSR rows as the four arrays and shape a scipy CSR matrix holds, without one around them: constructing it
    checks and converts its arrays (about 30 us, most of a frame's descriptor stage), and what reads a frame's
    histograms (`similarity.histogram_similarity`) reads only these fields."""

    indptr: np.ndarray  # (n + 1,) int
    indices: np.ndarray  # (nnz,) int, the columns
    data: np.ndarray  # (nnz,) float64
    shape: tuple[int, int]


def query_histograms(
    centers: np.ndarray,
    class_ids: np.ndarray,
    num_classes: int,
    d_adj: float,
    max_degree: int | None,
    walk_length: int = 3,
    kernel: sp.csr_matrix | None = None,
) -> SparseRows:
    """`semantic_histograms(semantic_graph(centers, d_adj, max_degree), ...)` of one frame's observations,
    with the same values (the same stored entries in the same order, so products with it sum alike), in one
    compiled pass instead of some thirty sparse-matrix constructions (most of a query's fixed cost).

    Falls back to the sparse path where the compiled one would differ or not pay: no observations, more
    than `max_degree` + 1 of them (the degree cap could bite), or too many classes for a dense prefix.
    """
    n = len(centers)
    if (n == 0 or walk_length < 1 or (max_degree is not None and n > max_degree + 1)
            or num_classes ** (walk_length - 1) > QUERY_BINS_LIMIT):
        histograms = semantic_histograms(semantic_graph(centers, d_adj, max_degree), class_ids, num_classes,
                                         walk_length, kernel)
        return SparseRows(histograms.indptr, histograms.indices, histograms.data, histograms.shape)
    if kernel is None:  # exact labels: the identity's CSR arrays (scipy's sp.identity took 25 us a query)
        kernel_rows = np.arange(num_classes + 1), np.arange(num_classes), np.ones(num_classes)
    else:
        kernel_rows = kernel.indptr, kernel.indices, np.asarray(kernel.data, dtype=np.float64)
    pointers, bins, values = _query_rows(np.ascontiguousarray(centers, dtype=np.float64), float(d_adj),
                                         np.asarray(class_ids, dtype=np.int64), *kernel_rows, num_classes, walk_length)
    return SparseRows(pointers, bins, values, (n, num_classes**walk_length))


@njit(cache=True)
def _query_rows(centers: np.ndarray, d_adj: float, class_ids: np.ndarray, kernel_pointers: np.ndarray,
                kernel_columns: np.ndarray, kernel_values: np.ndarray, num_classes: int,
                walk_length: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`query_histograms`' rows (pointers, bins, values): the graph, the soft labels, the walks and their
    normalization in one compiled call (five calls' dispatch cost more than a frame's walks), each row normalized
    as it is written (`_walk_histograms`' `normalized`)."""
    neighbour_pointers, neighbour_indices = _neighbours_within(centers, d_adj)
    label_pointers, label_bins, label_values = _kernel_rows(class_ids, kernel_pointers, kernel_columns, kernel_values)
    return _walk_histograms(neighbour_pointers, neighbour_indices, label_pointers, label_bins, label_values,
                            num_classes, walk_length, True)


def landmark_histograms(
    adjacency: sp.csr_matrix,
    class_ids: np.ndarray,
    num_classes: int,
    walk_length: int = 3,
    distributions: sp.csr_matrix | None = None,
) -> sp.csr_matrix:
    """`semantic_histograms(adjacency, class_ids, num_classes, walk_length, None, distributions)` of a map, to
    the bit (the same stored entries in the same order), in one compiled pass over the adjacency's rows: the
    sparse path's row-wise Kronecker products took seconds on a map of 47,000 landmarks (`index_map`).
    Falls back to the sparse path where the dense walk prefix would be too wide (`QUERY_BINS_LIMIT`)."""
    if walk_length < 1 or num_classes ** (walk_length - 1) > QUERY_BINS_LIMIT:
        return semantic_histograms(adjacency, class_ids, num_classes, walk_length, None, distributions)
    labels = (sp.csr_matrix(distributions) if distributions is not None
              else _label_rows(np.asarray(class_ids, dtype=np.int64), num_classes, None))
    pointers, bins, values = _walk_histograms(adjacency.indptr.astype(np.int64), adjacency.indices.astype(np.int64),
                                              labels.indptr.astype(np.int64), labels.indices.astype(np.int64),
                                              labels.data.astype(np.float64), num_classes, walk_length, True)
    return sp.csr_matrix((values, bins, pointers), shape=(adjacency.shape[0], num_classes**walk_length))


@njit(cache=True)
def _inverse_norms(pointers: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(n,) 1 / the L2 norm of each row (0 for a row of norm 0 or NaN), the formula of `_l2_normalized` (squares
    summed, np.sqrt, `np.where(norms > 0, 1 / np.maximum(norms, 1e-300), 0)`) in one pass instead of six calls."""
    n = len(pointers) - 1
    scale = np.zeros(n)
    for v in range(n):
        scale[v] = _inverse_norm(values, pointers[v], pointers[v + 1])
    return scale


@njit(cache=True, inline="always")
def _inverse_norm(values: np.ndarray, start: int, end: int) -> float:
    """1 / the L2 norm of values[start:end] as `_inverse_norms` computes a row's (0 for an empty row, norm 0 or NaN);
    the squares summed in order, within rounding of numpy's pairwise sum."""
    total = 0.0
    for i in range(start, end):
        total += values[i] * values[i]
    norm = np.sqrt(total)
    if norm > 0:
        return 1.0 / (norm if norm > 1e-300 else 1e-300)
    return 0.0


@njit(cache=True)
def _neighbours_within(centers: np.ndarray, d_adj: float) -> tuple[np.ndarray, np.ndarray]:
    """CSR rows (pointers, ascending indices) of `semantic_graph(centers, d_adj)`, by testing every pair
    (a frame's few observations)."""
    n = len(centers)
    pointers, indices = np.zeros(n + 1, np.int64), np.empty(n * max(n - 1, 0), np.int64)
    limit = d_adj * d_adj
    for i in range(n):
        at = pointers[i]
        for j in range(n):
            if i != j:
                dx, dy, dz = centers[i, 0] - centers[j, 0], centers[i, 1] - centers[j, 1], centers[i, 2] - centers[j, 2]
                squared = dx * dx + dy * dy + dz * dz
                if squared < limit and math.sqrt(squared) < d_adj:
                    indices[at] = j
                    at += 1
        pointers[i + 1] = at
    return pointers, indices[:pointers[n]]


@njit(cache=True)
def _kernel_rows(class_ids: np.ndarray, kernel_pointers: np.ndarray, kernel_columns: np.ndarray,
                 kernel_values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR rows (pointers, bins, values) of each node's (soft) label: its class's kernel row."""
    n = len(class_ids)
    pointers = np.zeros(n + 1, np.int64)
    for v in range(n):
        pointers[v + 1] = pointers[v] + kernel_pointers[class_ids[v] + 1] - kernel_pointers[class_ids[v]]
    bins, values = np.empty(pointers[n], np.int64), np.empty(pointers[n])
    for v in range(n):
        first = kernel_pointers[class_ids[v]]
        for e in range(pointers[v + 1] - pointers[v]):
            bins[pointers[v] + e], values[pointers[v] + e] = kernel_columns[first + e], kernel_values[first + e]
    return pointers, bins, values


@njit(cache=True)
def _walk_histograms(neighbour_pointers: np.ndarray, neighbour_indices: np.ndarray, label_pointers: np.ndarray,
                     label_bins: np.ndarray, label_values: np.ndarray, num_classes: int, walk_length: int,
                     normalized: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows (pointers, ascending bins, values) of the unnormalised Semantic Histograms of the graph with
    CSR rows (`neighbour_pointers`, `neighbour_indices`) and label rows (zeros left out): each sum adds
    its terms in the order scipy's sparse products do (neighbours in stored order), from 0.

    `normalized`: the rows as `_scale_rows(..., _inverse_norms(...))` stores them (L2-normalized, last bin
    first, zeros dropped), each written so while it is in cache and into arrays sized once by a bound, where a
    second pass and doubling arrays cost a third of a 47,000-landmark map's histograms."""
    n = len(neighbour_pointers) - 1
    # walks of one node: each node's label row without its zeros
    pointers = np.zeros(n + 1, np.int64)
    for v in range(n):
        count = 0
        for e in range(label_pointers[v], label_pointers[v + 1]):
            count += label_values[e] != 0
        pointers[v + 1] = pointers[v] + count
    bins, values = np.empty(pointers[n], np.int64), np.empty(pointers[n])
    for v in range(n):
        at = pointers[v]
        for e in range(label_pointers[v], label_pointers[v + 1]):
            if label_values[e] != 0:
                bins[at], values[at] = label_bins[e], label_values[e]
                at += 1
    if normalized and walk_length <= 1:
        return _scale_rows(pointers, bins, values, _inverse_norms(pointers, values))
    label_pointers, label_bins, label_values = pointers, bins, values
    width = num_classes
    for step in range(walk_length - 1):
        last = normalized and step == walk_length - 2
        total = np.zeros(width)
        seen = np.zeros(width, np.bool_)
        touched = np.empty(width, np.int64)
        next_pointers = np.zeros(n + 1, np.int64)
        next_bins, next_values = np.empty(0, np.int64), np.empty(0)
        row_bins, row_values = np.empty(0, np.int64), np.empty(0)  # the last step's row before it is normalized
        if last:
            bound = _row_bound(neighbour_pointers, neighbour_indices, pointers, label_pointers, width)
            next_bins, next_values = np.empty(bound, np.int64), np.empty(bound)
        for v in range(n):
            count = 0  # tails: the sum over v's neighbours of their walks
            for t in range(neighbour_pointers[v], neighbour_pointers[v + 1]):
                u = neighbour_indices[t]
                for e in range(pointers[u], pointers[u + 1]):
                    b = bins[e]
                    if not seen[b]:
                        seen[b] = True
                        total[b] = 0.0
                        touched[count] = b
                        count += 1
                    total[b] += values[e]
            if count * 8 > width:  # many tails of few bins: the marks read in bin order, not a sort
                count = 0
                for b in range(width):
                    if seen[b]:
                        touched[count] = b
                        count += 1
            elif count <= SORTED_IN_PLACE_UP_TO:
                sort_span(touched, 0, count)
            else:
                touched[:count].sort()
            labels = label_pointers[v + 1] - label_pointers[v]
            start = 0 if last else next_pointers[v]
            need = start + labels * count
            if last and need > len(row_bins):
                row_bins, row_values = np.empty(2 * need, np.int64), np.empty(2 * need)
            elif not last and need > len(next_bins):
                grown = max(need, 2 * len(next_bins))
                more_bins, more_values = np.empty(grown, np.int64), np.empty(grown)
                more_bins[:start], more_values[:start] = next_bins[:start], next_values[:start]
                next_bins, next_values = more_bins, more_values
            out_bins, out_values = (row_bins, row_values) if last else (next_bins, next_values)
            at = start
            for e in range(label_pointers[v], label_pointers[v + 1]):  # the row-wise Kronecker product
                for k in range(count):  # the tails touched[:count], read by index (a view is reference-counted)
                    b = touched[k]
                    out_bins[at], out_values[at] = label_bins[e] * width + b, label_values[e] * total[b]
                    at += 1
            if not _ascending(out_bins, start, at):  # it is when the label row is (a canonical kernel's rows are)
                order = np.argsort(out_bins[start:at])  # bins are distinct: any sort gives scipy's canonical order
                out_bins[start:at], out_values[start:at] = out_bins[start:at][order], out_values[start:at][order]
            if last:
                at = _append_scaled_reversed(next_bins, next_values, next_pointers[v], row_bins, row_values, 0, at,
                                             _inverse_norm(row_values, 0, at))
            next_pointers[v + 1] = at
            for k in range(count):
                seen[touched[k]] = False
        pointers, bins, values = next_pointers, next_bins[:next_pointers[n]], next_values[:next_pointers[n]]
        width *= num_classes
    return pointers, bins, values


@njit(cache=True)
def _row_bound(neighbour_pointers: np.ndarray, neighbour_indices: np.ndarray, pointers: np.ndarray,
               label_pointers: np.ndarray, width: int) -> int:
    """At least the entries of a walk step's rows: per node its labels times its neighbours' entries (or `width`)."""
    bound = 0
    for v in range(len(neighbour_pointers) - 1):
        tails = 0
        for t in range(neighbour_pointers[v], neighbour_pointers[v + 1]):
            u = neighbour_indices[t]
            tails += pointers[u + 1] - pointers[u]
        bound += (label_pointers[v + 1] - label_pointers[v]) * min(tails, width)
    return bound


@njit(cache=True, inline="always")
def sort_span(values: np.ndarray, start: int, stop: int) -> None:
    """values[start: stop].sort() of integers by an insertion sort in place: a row's few walk tails here, a clique's
    dozen members in clipclique.inliers, where a view's sort cost some 250 ns of reference counts and numba's
    quicksort setup (inlined into its callers)."""
    for i in range(start + 1, stop):
        value = values[i]
        j = i
        while j > start and values[j - 1] > value:
            values[j] = values[j - 1]
            j -= 1
        values[j] = value


@njit(cache=True)
def _scale_rows(pointers: np.ndarray, bins: np.ndarray, values: np.ndarray,
                scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`diags(scale) @ rows` as scipy's sparse product stores it: each row's entries last bin first, zeros dropped."""
    n = len(scale)
    out_pointers = np.zeros(n + 1, np.int64)
    out_bins, out_values = np.empty(len(bins), np.int64), np.empty(len(values))
    for v in range(n):
        out_pointers[v + 1] = _append_scaled_reversed(out_bins, out_values, out_pointers[v], bins, values, pointers[v],
                                                      pointers[v + 1], scale[v])
    return out_pointers, out_bins[:out_pointers[n]], out_values[:out_pointers[n]]


@njit(cache=True, inline="always")
def _append_scaled_reversed(out_bins: np.ndarray, out_values: np.ndarray, at: int, bins: np.ndarray,
                            values: np.ndarray, start: int, end: int, scale: float) -> int:
    """Writes `scale` times entries[start:end] last first, zeros dropped, at out[at:]; returns where it stopped."""
    for e in range(end - 1, start - 1, -1):
        value = scale * values[e]
        if value != 0:
            out_bins[at], out_values[at] = bins[e], value
            at += 1
    return at


@njit(cache=True, inline="always")
def _ascending(values: np.ndarray, start: int, stop: int) -> bool:
    """Whether values[start:stop] ascend, read by index (inlined: a view, or an array handed to a call, is
    reference-counted, and a frame's rows made a dozen such calls each)."""
    for i in range(start + 1, stop):
        if values[i] < values[i - 1]:
            return False
    return True
