"""Initial matching: which (observation, landmark) pairs become candidate correspondences.

Every strategy takes the (K, N) similarity matrix and returns `(candidates, scores)`: candidates
(C, 2) int rows of (observation, landmark), grouped by observation in row order and, within an
observation, best first; scores (C,) their similarities. Equal similarities are ordered by
landmark index (stable sort), so the result is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numba import njit

from clipclique.config import MatchingConfig

FLAT = 1e-12  # a row whose largest gap is at most this has no gap at all
PARTIAL_SORT_FROM = 1024  # landmarks: from here a row's best are picked by partition before sorting
SELECTED_UP_TO = 64  # m: up to here a row's best are picked by insertion into a sorted list (compiled), not argsort


def match(similarity: np.ndarray, config: MatchingConfig,
          lookalikes: Lookalikes | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The configured strategy, then candidates at or below `config.min_similarity` dropped: the candidates,
    their scores, and (C,) which of them only `with_lookalikes` added.

    Adaptive matching also keeps, per observation, its `config.lookalike_candidates` most similar
    landmarks of each class its detector confuses with its own, of a size with it (`lookalikes`)."""
    added = None
    if config.strategy == "adaptive":
        m = top_m(similarity.shape[1], config.top_m_fraction)
        if config.lookalike_candidates and lookalikes is not None and _few(similarity.shape, m):
            return _few_with_lookalikes(similarity, m, lookalikes, config)
        candidates = adaptive_matches(similarity, m)
        if config.lookalike_candidates and lookalikes is not None:
            candidates, added = with_lookalikes(candidates, similarity, lookalikes, config.lookalike_candidates,
                                                config.lookalike_size_ratio)
    elif config.strategy == "knn":
        candidates = knn_matches(similarity, config.k)
    else:
        candidates = mutual_best_matches(similarity)
    added = np.zeros(len(candidates), bool) if added is None else added
    return _above(similarity, candidates, added, float(config.min_similarity))


@njit(cache=True)
def _above(similarity: np.ndarray, candidates: np.ndarray, added: np.ndarray,
           floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The `candidates` (C, 2) whose similarity is above `floor` (NaN is not), their scores, and their `added`
    flags: one compiled pass where the gather, the comparison and three selections were seven numpy calls."""
    keep = np.empty(len(candidates), np.bool_)
    for c in range(len(candidates)):
        keep[c] = similarity[candidates[c, 0], candidates[c, 1]] > floor
    count = keep.sum()
    kept, scores, flags = np.empty((count, 2), np.int64), np.empty(count, similarity.dtype), np.empty(count, np.bool_)
    at = 0
    for c in range(len(candidates)):
        if keep[c]:
            kept[at, 0], kept[at, 1] = candidates[c, 0], candidates[c, 1]
            scores[at], flags[at] = similarity[candidates[c, 0], candidates[c, 1]], added[c]
            at += 1
    return kept, scores, flags


def _few(shape: tuple[int, int], m: int) -> bool:
    """Whether adaptive matching of a (K, N) similarity picks its top `m` by the compiled insertion (`_adaptive_few`)
    for certain: some observations, short rows (not `_partial`) and 1 <= m <= SELECTED_UP_TO."""
    return shape[0] > 0 and 1 <= m <= SELECTED_UP_TO and not _partial(shape[1], m)


def _few_with_lookalikes(similarity: np.ndarray, m: int, lookalikes: Lookalikes,
                         config: MatchingConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`match`'s adaptive matching with look-alikes where `_few`: the gap rule, the look-alikes and the floor in
    one compiled call, where three (their arguments, results and code each fetched anew a query) took 45 us of
    match's 56 in a desk query's context."""
    groups = lookalikes.groups
    return _few_merged_above(similarity, m, np.asarray(lookalikes.classes, np.int64), lookalikes.axes,
                             groups.landmarks, groups.starts, groups.lookalike_starts, groups.lookalikes, groups.axes,
                             config.lookalike_candidates, config.lookalike_size_ratio, float(config.min_similarity))


@njit(cache=True)
def _few_merged_above(similarity, m, observed_classes, observed_axes, landmarks, starts, lookalike_starts,
                      lookalikes, landmark_axes, per_class, ratio, floor):
    """`_adaptive_few`, `with_lookalikes` (its candidates as they came when none was of a size) and `_above`."""
    candidates = _adaptive_few(similarity, m)
    merged, added, found = _merge_lookalikes(candidates, similarity, observed_classes, observed_axes, landmarks,
                                             starts, lookalike_starts, lookalikes, landmark_axes, per_class, ratio)
    if not found:
        merged, added = candidates, np.zeros(len(candidates), np.bool_)
    return _above(similarity, merged, added, floor)


def cap(candidates: np.ndarray, scores: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """At most `limit` candidates: the best-scored (ties by row), in their original row order;
    and whether any were dropped. A flat similarity on a map of thousands of look-alike landmarks
    would otherwise keep a quarter of the map per observation."""
    kept = best_rows(scores, limit)
    if kept is None:
        return candidates, scores, False
    return candidates[kept], scores[kept], True


def best_rows(scores: np.ndarray, limit: int) -> np.ndarray | None:
    """The rows `cap` keeps (sorted), None when all `scores` fit within `limit`."""
    if len(scores) <= limit:
        return None
    return np.sort(np.argsort(-scores, kind="stable")[:limit])


def top_m(num_landmarks: int, fraction: float) -> int:
    """M for adaptive matching: `ceil(fraction * N)`, at least 2 (one gap), at most N."""
    return min(num_landmarks, max(2, math.ceil(fraction * num_landmarks)))


def adaptive_matches(similarity: np.ndarray, m: int) -> np.ndarray:
    """Per observation, the landmarks above the largest similarity gap among its top `m`.

    Sorted descending, the top m values have m - 1 gaps; the candidates are those before the
    largest gap. Ties between equal gaps go to the first (the fewest, most confident
    candidates). A flat row (no gap larger than FLAT) gives no reason to prefer any landmark:
    all m are kept. With m < 2 (a map of one landmark) there is no gap: the best one is kept.
    """
    num_obs, num_landmarks = similarity.shape
    if num_obs and m >= 2 and _partial(num_landmarks, m) and not np.isnan(similarity).any():
        return _adaptive_long_rows(similarity, m)  # m <= num_landmarks / 2 here
    m = min(m, num_landmarks)
    if num_obs == 0 or m == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if m <= SELECTED_UP_TO:
        return _adaptive_few(similarity, m)
    # one compiled layout: one cache load
    return _before_largest_gap(similarity, np.ascontiguousarray(_best_first(similarity, m)))


@dataclass(frozen=True)
class ClassGroups:
    """The map's landmarks grouped by class and each class's look-alike classes, built once per map
    (`index_map`), so a query scans only the landmarks of its look-alike classes: a (K, N) mask and its
    sort cost 25 ms of a 59 ms query at 47,000 landmarks."""

    landmarks: np.ndarray  # (N,) landmark indices by class, ascending within a class
    starts: np.ndarray  # (C + 1,) class c's landmarks are landmarks[starts[c]:starts[c + 1]]
    lookalike_starts: np.ndarray  # (C + 1,) class c's look-alikes are lookalikes[lookalike_starts[c]:...[c + 1]]
    lookalikes: np.ndarray  # classes with a positive kernel entry to c, c itself excluded
    axes: np.ndarray  # (N, 3) float64 each landmark's semi-axes, sorted


class Lookalikes(NamedTuple):
    """What `with_lookalikes` needs of one query: the map's class groups and each observation's class and size (a
    named tuple: a frozen dataclass took 1 us a query to build)."""

    groups: ClassGroups
    classes: np.ndarray  # (K,) each observation's class
    axes: np.ndarray  # (K, 3) float64 each observation's semi-axes (`_merge_lookalikes` sorts each row)


def class_groups(landmark_classes: np.ndarray, kernel: sp.csr_matrix, landmark_axes: np.ndarray) -> ClassGroups:
    """`ClassGroups` of a map whose landmarks have classes `landmark_classes` (N,) and semi-axes (N, 3), look-alike
    classes being those with a positive entry in the class `kernel` (C, C) (lookalikes.class_kernel)."""
    num_classes = kernel.shape[0]
    kernel = sp.coo_matrix(kernel)
    pairs = (kernel.data > 0) & (kernel.row != kernel.col)
    order = np.lexsort((kernel.col[pairs], kernel.row[pairs]))
    return ClassGroups(landmarks=np.argsort(landmark_classes, kind="stable").astype(np.int64),
                       starts=_starts(np.asarray(landmark_classes), num_classes),
                       lookalike_starts=_starts(kernel.row[pairs], num_classes),
                       lookalikes=kernel.col[pairs][order].astype(np.int64),
                       axes=np.sort(np.asarray(landmark_axes, np.float64), axis=1))


def with_lookalikes(candidates: np.ndarray, similarity: np.ndarray, lookalikes: Lookalikes, per_class: int,
                    size_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """`candidates` plus each observation's `per_class` most similar landmarks of every look-alike class of its
    own whose sorted semi-axes are within `size_ratio` of its own on every axis, in the candidates' order (by
    observation, best first, ties by landmark index; NaN last), and (C,) which of them were added.

    A detection of a cup labelled "bottle" matches the map's bottles far better than its cups (the class
    term), so the largest similarity gap falls between the two classes and the right cup is never a
    candidate: on a cluttered desk four in five such detections lost their landmark so. Its best cups
    (by their neighbourhoods) come back as lighter candidates; a clique still needs them to agree. The size
    test: of the added candidates on a cluttered desk the right ones differ by a median factor of 1.3, the
    wrong ones by 2.1 (a cup is not a bowl's size)."""
    if per_class == 0:
        return candidates, np.zeros(len(candidates), bool)
    groups = lookalikes.groups
    merged, added, found = _merge_lookalikes(
        np.ascontiguousarray(candidates, np.int64), similarity, np.asarray(lookalikes.classes, np.int64),
        lookalikes.axes, groups.landmarks, groups.starts, groups.lookalike_starts, groups.lookalikes, groups.axes,
        per_class, size_ratio)
    if not found:  # nothing to add: the candidates as they came
        return candidates, np.zeros(len(candidates), bool)
    return merged, added


def knn_matches(similarity: np.ndarray, k: int) -> np.ndarray:
    """Per observation, its k most similar landmarks (all of them when the map has fewer)."""
    k = min(k, similarity.shape[1])
    if similarity.shape[0] == 0 or k == 0:
        return np.zeros((0, 2), dtype=np.int64)
    few = k <= SELECTED_UP_TO and not _partial(similarity.shape[1], k)  # by insertion, as adaptive matching's
    order = _best_few(similarity, k) if few else _best_first(similarity, k)
    return _pairs(order, np.ones(order.shape, dtype=bool))


def mutual_best_matches(similarity: np.ndarray) -> np.ndarray:
    """1-to-1: pairs that are each other's best (first index on ties)."""
    if similarity.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    best_landmark = similarity.argmax(axis=1)
    best_observation = similarity.argmax(axis=0)
    observations = np.flatnonzero(best_observation[best_landmark] == np.arange(similarity.shape[0]))
    return np.column_stack((observations, best_landmark[observations])).astype(np.int64)


def _best_first(similarity: np.ndarray, count: int) -> np.ndarray:
    """(K, count) landmark indices of each row's largest values, best first, ties by index: the first
    `count` of a stable descending sort. Of a long row only those are sorted (adaptive matching keeps
    a quarter of the map, and sorting all of 47,000 landmarks per observation dominated the stage)."""
    negated = -similarity
    if not _partial(similarity.shape[1], count):
        return np.argsort(negated, axis=1, kind="stable")[:, :count]
    kth = np.partition(negated, count - 1, axis=1)[:, count - 1]  # each row's count-th best value
    if np.isnan(kth).any():  # NaN sorts last in argsort; keep its semantics
        return np.argsort(negated, axis=1, kind="stable")[:, :count]
    best = np.empty((len(negated), count), np.int64)
    for i, (row, value) in enumerate(zip(negated, kth)):
        better = np.flatnonzero(row < value)
        chosen = np.sort(np.concatenate((better, np.flatnonzero(row == value)[:count - len(better)])))
        best[i] = chosen[np.argsort(row[chosen], kind="stable")]  # by value, ties by index
    return best


def _partial(num_landmarks: int, count: int) -> bool:
    """Whether a row's `count` best are picked by partition rather than by sorting the whole row."""
    return 2 * count <= num_landmarks and num_landmarks >= PARTIAL_SORT_FROM


def _adaptive_long_rows(similarity: np.ndarray, m: int) -> np.ndarray:
    """`adaptive_matches` of long rows without NaN, the same pairs in the same order: the top m values come
    sorted from a partition (values only), and only the landmarks above the gap are ordered. Above a gap
    larger than FLAT the kept value is strictly above the next, so the kept landmarks are exactly those at
    or above it; a flat row keeps all m, ordered as `_best_first` does."""
    values = -np.sort(np.partition(-similarity, m - 1, axis=1)[:, :m], axis=1)  # (K, m) each row's best, descending
    gaps = values[:, :-1] - values[:, 1:]
    count = np.where(gaps.max(axis=1) > FLAT, gaps.argmax(axis=1) + 1, m)
    kept = []
    for row, last, number in zip(similarity, values[np.arange(len(values)), count - 1], count):
        if number == m:
            kept.append(_best_first(row[None], m)[0])
        else:
            chosen = np.flatnonzero(row >= last)  # ascending: ties by landmark index after the stable sort
            kept.append(chosen[np.argsort(-row[chosen], kind="stable")])
    return np.column_stack((np.repeat(np.arange(len(similarity)), count), np.concatenate(kept))).astype(np.int64)


def _pairs(order: np.ndarray, keep: np.ndarray) -> np.ndarray:
    rows = np.broadcast_to(np.arange(order.shape[0])[:, None], order.shape)
    return np.column_stack((rows[keep], order[keep])).astype(np.int64)


@njit(cache=True)
def _before_largest_gap(similarity: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(C, 2) each row's landmarks in `order` (K, m) before the first largest gap between consecutive
    values, all m where no gap exceeds FLAT or one is NaN, the first alone where m < 2: a dozen small
    numpy calls per query in one compiled pass, the same comparisons and subtractions."""
    num_obs, m = order.shape
    count = np.ones(num_obs, np.int64)
    for i in range(num_obs if m >= 2 else 0):
        largest, first, undefined = -np.inf, 0, False
        for j in range(m - 1):
            gap = similarity[i, order[i, j]] - similarity[i, order[i, j + 1]]
            undefined |= np.isnan(gap)
            if gap > largest:
                largest, first = gap, j
        count[i] = first + 1 if largest > FLAT and not undefined else m
    pairs = np.empty((count.sum(), 2), np.int64)
    at = 0
    for i in range(num_obs):
        for j in range(count[i]):
            pairs[at, 0], pairs[at, 1] = i, order[i, j]
            at += 1
    return pairs


@njit(cache=True)
def _adaptive_few(similarity: np.ndarray, m: int) -> np.ndarray:
    """`adaptive_matches` for 1 <= m <= SELECTED_UP_TO in one compiled call: numpy's stable argsort of a
    frame's (K, N) took most of the matching stage."""
    return _before_largest_gap(similarity, _best_few(similarity, m))


@njit(cache=True)
def _best_few(similarity: np.ndarray, m: int) -> np.ndarray:
    """`_best_first(similarity, m)` (1 <= m <= N) by inserting each landmark, in index order, into its row's sorted
    list of the m best so far: `_ranks_before` is a total order (value, NaN last, then index), so this is the
    stable argsort's order, at most m comparisons a landmark."""
    num_obs, num_landmarks = similarity.shape
    order = np.empty((num_obs, m), np.int64)
    for i in range(num_obs):
        row, best = similarity[i], order[i]
        count = 0
        for landmark in range(num_landmarks):
            value = row[landmark]
            if count == m and not _ranks_before(value, landmark, row[best[m - 1]], best[m - 1]):
                continue
            place = min(count, m - 1)  # a full list drops its last
            while place > 0 and _ranks_before(value, landmark, row[best[place - 1]], best[place - 1]):
                best[place] = best[place - 1]
                place -= 1
            best[place] = landmark
            count = min(count + 1, m)
    return order


def _starts(values: np.ndarray, count: int) -> np.ndarray:
    """(count + 1,) where each value's run begins in `values` sorted."""
    return np.r_[0, np.cumsum(np.bincount(values, minlength=count))].astype(np.int64)


@njit(cache=True)
def _ranks_before(value_a: float, index_a: int, value_b: float, index_b: int) -> bool:
    """Whether (value_a, index_a) comes first: the larger value, NaN last, ties by the smaller index (numpy's
    lexsort of the negated values, then the indices)."""
    if np.isnan(value_a) or np.isnan(value_b):
        return not np.isnan(value_a) or (np.isnan(value_b) and index_a < index_b)
    return value_a > value_b or (value_a == value_b and index_a < index_b)


@njit(cache=True)
def _apart(observed: np.ndarray, mapped: np.ndarray, ratio: float) -> bool:
    """Whether two sorted semi-axes (3,) differ by more than `ratio` on some axis (NaN: not apart)."""
    for axis in range(3):
        a, b = observed[axis], mapped[axis]
        if not (np.isnan(a) or np.isnan(b)) and max(a, b) > ratio * min(a, b):
            return True
    return False


@njit(cache=True, inline="always")
def _best_of(similarity_row, landmarks, observed_axes, landmark_axes, ratio, best):
    """How many of `landmarks` are of a size with the observation's, their best (at most len(best)) put into
    `best` in rank order: an insertion into a short sorted list."""
    count = found = 0
    for landmark in landmarks:
        if _apart(observed_axes, landmark_axes[landmark], ratio):
            continue
        found += 1
        place = count
        while place > 0 and _ranks_before(similarity_row[landmark], landmark,
                                          similarity_row[best[place - 1]], best[place - 1]):
            place -= 1
        if place < len(best):
            for j in range(min(count, len(best) - 1), place, -1):  # shifted in place: a copy was an allocation
                best[j] = best[j - 1]
            best[place] = landmark
            count = min(count + 1, len(best))
    return count, found


@njit(cache=True)
def _merge_lookalikes(candidates, similarity, observed_classes, observed_axes, landmarks, starts,
                      lookalike_starts, lookalikes, landmark_axes, per_class, ratio):
    """`with_lookalikes` in one compiled pass per observation over only its look-alike classes' landmarks:
    (C, 2) merged, (C,) added, and how many look-alike landmarks were of a size (0: nothing to merge). Each
    observation's semi-axes are sorted here (numpy's sort of a frame's (K, 3) was a tenth of the matching stage)."""
    num_obs = similarity.shape[0]
    sorted_axes = np.empty((num_obs, 3))
    for i in range(num_obs):
        sorted_axes[i, 0], sorted_axes[i, 1], sorted_axes[i, 2] = sorted3(observed_axes, i)
    row_starts = np.zeros(num_obs + 1, np.int64)
    for c in range(len(candidates)):
        row_starts[candidates[c, 0] + 1] += 1
    row_starts = np.cumsum(row_starts)
    at = row_starts[:-1].copy()
    by_row = np.empty(len(candidates), np.int64)  # the candidates' columns grouped by row, in their order
    for c in range(len(candidates)):
        by_row[at[candidates[c, 0]]] = candidates[c, 1]
        at[candidates[c, 0]] += 1
    capacity = np.zeros(num_obs, np.int64)  # per row: its candidates and at most per_class of each class
    for i in range(num_obs):
        capacity[i] = row_starts[i + 1] - row_starts[i]
        own = observed_classes[i]
        for group in lookalikes[lookalike_starts[own]:lookalike_starts[own + 1]]:
            capacity[i] += min(per_class, starts[group + 1] - starts[group])
    merged = np.empty((capacity.sum(), 2), np.int64)
    flags = np.empty(capacity.sum(), np.bool_)
    best = np.empty(per_class, np.int64)
    widest = capacity.max() if num_obs else 0  # one row's scratch, made once (three allocations a row before)
    columns, added, order = np.empty(widest, np.int64), np.empty(widest, np.bool_), np.empty(widest, np.int64)
    size = found = 0
    for i in range(num_obs):
        count = row_starts[i + 1] - row_starts[i]
        for j in range(count):
            columns[j], added[j] = by_row[row_starts[i] + j], False
        own = observed_classes[i]
        for group in lookalikes[lookalike_starts[own]:lookalike_starts[own + 1]]:
            kept, eligible = _best_of(similarity[i], landmarks[starts[group]:starts[group + 1]], sorted_axes[i],
                                      landmark_axes, ratio, best)
            columns[count:count + kept] = best[:kept]
            added[count:count + kept] = True
            count += kept
            found += eligible
        for j in range(count):  # an insertion sort by rank: stable, and a row is short
            place = j
            while place > 0 and _ranks_before(similarity[i, columns[j]], columns[j],
                                              similarity[i, columns[order[place - 1]]], columns[order[place - 1]]):
                order[place] = order[place - 1]
                place -= 1
            order[place] = j
        first = size
        for j in order[:count]:
            if size > first and merged[size - 1, 1] == columns[j]:  # the same pair twice: added only if both were
                flags[size - 1] &= added[j]
                continue
            merged[size, 0], merged[size, 1], flags[size] = i, columns[j], added[j]
            size += 1
    return merged[:size], flags[:size], found


@njit(cache=True, inline="always")
def sorted3(values: np.ndarray, row: int) -> tuple[float, float, float]:
    """np.sort of the three values of values[row]: ascending, NaN last, equal values in their order (numpy's
    insertion sort); read by index (a row view is reference-counted, and numpy's sort of one cost 250 ns)."""
    a, b, c = values[row, 0], values[row, 1], values[row, 2]
    if _sorts_before(b, a):
        a, b = b, a
    if _sorts_before(c, b):
        b, c = c, b
        if _sorts_before(b, a):
            a, b = b, a
    return a, b, c


@njit(cache=True)
def _sorts_before(x: float, y: float) -> bool:
    """numpy's sort order: x < y, NaN after every number."""
    return x < y or (np.isnan(y) and not np.isnan(x))
