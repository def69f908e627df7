"""The compatibility graph of candidate correspondences, and the slack of objects seen in part.

Nodes are candidate correspondences `(observation, landmark)`. Two candidates a, b are compatible
when a rigid motion could explain both, i.e. the distance between their observations equals the
distance between their landmarks up to `d_comp`: `| |o_a - o_b| - |m_a - m_b| | < d_comp`, and
they share neither the observation nor the landmark (one object cannot be two, so a clique is a
one-to-one correspondence set). The pipeline then asks `cliquesearch.top_cliques` for the
heaviest maximal cliques of this graph.

Memory is bounded whatever the map: `affordable_candidates` keeps the best-scored candidates
whose landmark pairs within reach fit `max_pairs` (5,000 identical overlapping landmarks would
otherwise ask for gigabytes of pairs), and the pipeline reports the cap it used.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from clipclique.descriptors.matching import sorted3

ALL_PAIRS_UP_TO = 128  # candidates: up to here every pair is tested (8 us of 100, where a KD-tree took 36)


def compatibility_graph(
    observed_centers: np.ndarray,
    landmark_centers: np.ndarray,
    candidates: np.ndarray,
    d_comp: float,
    slack: np.ndarray | None = None,
    objects: np.ndarray | None = None,
) -> np.ndarray:
    """(E, 2) edges `i < j` between compatible candidates (rows of `candidates`).

    `slack` (C,) widens the test per candidate: pair (a, b) passes within
    `d_comp + slack[a] + slack[b]` metres (None: `d_comp` for every pair). `objects` (K,) names the
    object each observation shows (None: each its own): candidates of one object are never compatible.

    Two landmarks farther apart than the widest observation pair plus the widest tolerance
    cannot pass the test, so only landmark pairs within that reach (a KD-tree query) are tested:
    the cost grows with the candidates' neighbourhoods, not with the square of their number. Up to
    ALL_PAIRS_UP_TO candidates every pair is tested instead, in one compiled call (`_small_graph`); the edges
    come in the order `_pairs_in_reach` lists them.
    """
    if len(candidates) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    slack = np.zeros(len(candidates)) if slack is None else np.asarray(slack, dtype=np.float64)
    obs, lm = candidates[:, 0], candidates[:, 1]
    if len(candidates) <= ALL_PAIRS_UP_TO:
        objects = np.arange(len(observed_centers)) if objects is None else objects
        return _small_graph(np.ascontiguousarray(observed_centers, np.float64),
                            np.ascontiguousarray(landmark_centers, np.float64), np.asarray(obs, np.int64),
                            np.asarray(lm, np.int64), np.asarray(objects, np.int64), float(d_comp), slack)
    shown = obs if objects is None else np.asarray(objects, dtype=np.int64)[obs]
    observed = pair_distances(observed_centers)
    points = np.asarray(landmark_centers).take(lm, axis=0)  # take: a row gather, quicker than fancy indexing
    return _compatible(_pairs_in_reach(points, pair_reach(observed, d_comp, slack)), points, obs, shown, lm, observed,
                       d_comp, slack)


@njit(cache=True)
def _small_graph(observed_centers: np.ndarray, landmark_centers: np.ndarray, obs: np.ndarray, lm: np.ndarray,
                 objects: np.ndarray, d_comp: float, slack: np.ndarray) -> np.ndarray:
    """`compatibility_graph` of at most ALL_PAIRS_UP_TO candidates in one compiled call: the gather, the pair
    distances, the reach, the pairs within it (`_all_pairs_within`) and the rigid test, where five calls, their
    arguments and the arrays they handed back cost a small frame more than its pairs (and a KD-tree's construction
    and query alone 12 to 36 us of 17 to 100 candidates)."""
    points = np.empty((len(lm), 3))
    shown = np.empty(len(obs), np.int64)
    for c in range(len(lm)):
        points[c, 0], points[c, 1], points[c, 2] = (landmark_centers[lm[c], 0], landmark_centers[lm[c], 1],
                                                    landmark_centers[lm[c], 2])
        shown[c] = objects[obs[c]]
    observed = _pair_distances(observed_centers)
    pairs = _all_pairs_within(points, _reach(observed.reshape(-1), d_comp, slack))
    return _compatible(pairs, points, obs, shown, lm, observed, d_comp, slack)


def _pairs_in_reach(points: np.ndarray, reach: float) -> np.ndarray:
    """(P, 2) int64 pairs i < j of `points` (C, 3) at most `reach` apart, the pairs `cKDTree.query_pairs` finds: up to
    ALL_PAIRS_UP_TO points every pair tested, in order (i, then j: `_all_pairs_within`), beyond in the tree's order.
    The clique search orders equal candidates by it, so that the maximal cliques it reaches before its cut (not the
    cliques it finds) can differ with it where weights tie."""
    if len(points) <= ALL_PAIRS_UP_TO:
        return _all_pairs_within(np.asarray(points, np.float64), float(reach))
    return cKDTree(points).query_pairs(reach, output_type="ndarray").astype(np.int64, copy=False)


@njit(cache=True)
def _all_pairs_within(points: np.ndarray, reach: float) -> np.ndarray:
    """The pairs of `cKDTree(points).query_pairs(reach)` of points (C, 3), every pair i < j tested in order: those
    whose squared distance (`_squared_distance`, summed as the tree sums it) is at most reach * reach, as the tree
    compares (a negative reach squared too, NaN none); the tree's ValueError on a point that is not finite."""
    for i in range(len(points)):
        for k in range(3):
            if not np.isfinite(points[i, k]):
                raise ValueError("data must be finite, check for nan or inf values")
    bound = reach * reach
    pairs = np.empty((len(points) * (len(points) - 1) // 2, 2), np.int64)
    count = 0
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            if _squared_distance(points, i, j) <= bound:
                pairs[count, 0], pairs[count, 1] = i, j
                count += 1
    return pairs[:count]


@njit(cache=True, inline="always")
def _squared_distance(points: np.ndarray, a: int, b: int) -> float:
    """|points[a] - points[b]|^2 as (dx^2 + dy^2) + dz^2, rows read by index (no views)."""
    dx, dy, dz = points[a, 0] - points[b, 0], points[a, 1] - points[b, 1], points[a, 2] - points[b, 2]
    return (dx * dx + dy * dy) + dz * dz


def pair_distances(centers: np.ndarray) -> np.ndarray:
    """(K, K) distances between the centres (K, 3), `np.linalg.norm(centers[:, None] - centers[None], axis=-1)`
    in one compiled pass (the numpy form's temporaries cost a frame's compatibility stage a fifth of its time)."""
    return _pair_distances(np.ascontiguousarray(centers, np.float64))


@njit(cache=True)
def _pair_distances(centers: np.ndarray) -> np.ndarray:
    count = len(centers)
    distances = np.empty((count, count))
    for i in range(count):
        for j in range(count):
            dx, dy, dz = centers[i, 0] - centers[j, 0], centers[i, 1] - centers[j, 1], centers[i, 2] - centers[j, 2]
            distances[i, j] = np.sqrt((dx * dx + dy * dy) + dz * dz)
    return distances


@njit(cache=True)
def _compatible(pairs, points, obs, shown, lm, observed, d_comp, slack):
    """The pairs that pass the rigid distance test, in one compiled pass (vectorized numpy made
    six temporaries of the pair count: 10x slower at 300,000 pairs)."""
    keep = np.zeros(len(pairs), np.bool_)
    for p in range(len(pairs)):
        a, b = pairs[p, 0], pairs[p, 1]
        if shown[a] == shown[b] or lm[a] == lm[b]:
            continue
        mapped = math.sqrt(_squared_distance(points, a, b))
        keep[p] = abs(observed[obs[a], obs[b]] - mapped) < d_comp + slack[a] + slack[b]
    return pairs[keep]


def affordable_candidates(
    observed_centers: np.ndarray,
    landmark_centers: np.ndarray,
    candidates: np.ndarray,
    scores: np.ndarray,
    d_comp: float,
    slack: np.ndarray | None = None,
    *,
    max_pairs: int,
) -> np.ndarray:
    """Indices (sorted) of the candidates `compatibility_graph` may test without holding more
    than `max_pairs` pairs: all of them when they fit, else the longest best-scored run (ties by
    row) that fits, found by bisection on pair counts (a KD-tree's dual-tree count: no pairs
    are materialized, memory stays linear in the candidates)."""
    if len(candidates) * (len(candidates) - 1) // 2 <= max_pairs:
        return np.arange(len(candidates))
    observed = pair_distances(observed_centers)
    reach = pair_reach(observed, d_comp, slack)
    points = landmark_centers[candidates[:, 1]]
    if _pairs_bound(points, reach) <= max_pairs or _pairs_within(points, reach) <= max_pairs:
        return np.arange(len(candidates))
    best = np.argsort(-scores, kind="stable")
    fits, too_many = 0, len(candidates)  # bisection bounds on the run's length
    while too_many - fits > 1:
        middle = (fits + too_many) // 2
        if _pairs_within(points[best[:middle]], reach) <= max_pairs:
            fits = middle
        else:
            too_many = middle
    return np.sort(best[:fits])


def _pairs_within(points: np.ndarray, reach: float) -> int:
    """Pairs of distinct points at most `reach` apart, counted without listing them."""
    tree = cKDTree(points)
    return (int(tree.count_neighbors(tree, reach)) - len(points)) // 2


def _pairs_bound(points: np.ndarray, reach: float) -> int:
    """At least the pairs of distinct points at most `reach` apart, from a grid of cells a hair wider than
    `reach` (such a pair lies in one cell or two touching ones): the pairs of each cell and of each two
    touching cells. Linear and cheap; on a map of far-apart rooms it is near the true count."""
    cells = np.floor(points / (reach * (1 + 1e-9) + 1e-9)).astype(np.int64)
    cells -= cells.min(axis=0) - 1  # every cell and its neighbours at coordinates >= 0
    span = cells.max(axis=0) + 2
    if float(np.prod(span.astype(np.float64))) > 2.0**62:  # keys would overflow: a tiny reach over a huge map
        return len(points) * (len(points) - 1) // 2
    keys, counts = np.unique((cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2], return_counts=True)
    total = int(np.sum(counts * (counts - 1) // 2))
    for offset in itertools.product((-1, 0, 1), repeat=3):
        if offset > (0, 0, 0):  # each unordered pair of touching cells once
            neighbour = keys + (offset[0] * span[1] + offset[1]) * span[2] + offset[2]
            at = np.minimum(np.searchsorted(keys, neighbour), len(keys) - 1)
            total += int(np.sum(np.where(keys[at] == neighbour, counts * counts[at], 0)))
    return total


def pair_reach(observed: np.ndarray, d_comp: float, slack: np.ndarray | None) -> float:
    """Farthest landmark pair that can pass the test: the widest observation pair plus the widest tolerance,
    `float(observed.max()) + d_comp + 2.0 * float(slack.max())` (no slack: + 0.0) in one compiled pass (the two
    numpy reductions cost more than the graph's test of a sparse frame's pairs)."""
    return _reach(observed.reshape(-1), float(d_comp), _NO_SLACK if slack is None else slack.reshape(-1))


_NO_SLACK = np.zeros(0)


@njit(cache=True)
def _reach(observed: np.ndarray, d_comp: float, slack: np.ndarray) -> float:
    """`pair_reach` of the distances and slack flattened (ValueError on no distances, as numpy's reduction)."""
    if len(observed) == 0:
        raise ValueError("zero-size array to reduction operation maximum which has no identity")
    widest = 0.0 if len(slack) == 0 else 2.0 * slack.max()
    return observed.max() + d_comp + widest


def partial_view_slack(
    observed_axes: np.ndarray, landmark_axes: np.ndarray, fraction: float, cap: float, min_deficit: float
) -> np.ndarray:
    """(C,) extra compatibility tolerance per candidate for objects seen in part.

    Seeing a part of length l of an object whose semi-axis is L moves the observed centre by up
    to L - l/2 = L - (observed semi-axis) along that axis. The deficit is compared axis by axis
    after sorting both sets of semi-axes (their order is not comparable). Only a deficit of at
    least `min_deficit` metres earns slack (a smaller one the test already absorbs; widening it
    for the many small objects of a cluttered desk adds false edges): `fraction` of it, at most
    `cap` metres. A complete view gets none.
    """
    if fraction == 0 or len(observed_axes) == 0:
        return np.zeros(len(observed_axes))
    rows = np.arange(len(observed_axes))
    return _slack(np.ascontiguousarray(observed_axes, np.float64), np.ascontiguousarray(landmark_axes, np.float64),
                  rows, rows, float(fraction), float(cap), float(min_deficit))


def candidate_slack(observed_axes: np.ndarray, landmark_axes: np.ndarray, candidates: np.ndarray, fraction: float,
                    cap: float, min_deficit: float) -> np.ndarray:
    """`partial_view_slack(observed_axes[candidates[:, 0]], landmark_axes[candidates[:, 1]], ...)` of (C, 2)
    candidates, the rows read where they lie (two gathers fewer a query)."""
    if fraction == 0 or len(candidates) == 0:
        return np.zeros(len(candidates))
    return _slack(np.ascontiguousarray(observed_axes, np.float64), np.ascontiguousarray(landmark_axes, np.float64),
                  candidates[:, 0], candidates[:, 1], float(fraction), float(cap), float(min_deficit))


@njit(cache=True)
def _slack(observed_axes: np.ndarray, landmark_axes: np.ndarray, observed_rows: np.ndarray, landmark_rows: np.ndarray,
           fraction: float, cap: float, min_deficit: float) -> np.ndarray:
    """`partial_view_slack` of the rows `observed_rows` and `landmark_rows` in one compiled pass, as numpy's passes
    computed it: `np.where(deficit >= min_deficit, np.minimum(fraction * deficit, cap), 0)`, the deficit the largest
    difference of the sorted semi-axes (NaN sorted last, a NaN difference the largest), a handful of (C, 3)
    temporaries fewer."""
    slack = np.zeros(len(observed_rows))
    for c in range(len(observed_rows)):
        observed, mapped = sorted3(observed_axes, observed_rows[c]), sorted3(landmark_axes, landmark_rows[c])
        deficit = mapped[0] - observed[0]
        for axis in range(1, 3):
            difference = mapped[axis] - observed[axis]
            if not (deficit >= difference or np.isnan(deficit)):  # np.maximum's choice: NaN wins
                deficit = difference
        if deficit >= min_deficit:
            scaled = fraction * deficit
            slack[c] = scaled if scaled <= cap or np.isnan(scaled) else cap
    return slack
