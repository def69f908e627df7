"""Initial matching: which (observation, landmark) pairs become candidate correspondences.

Every strategy takes the (K, N) similarity matrix and returns `(candidates, scores)`: candidates
(C, 2) int rows of (observation, landmark), grouped by observation in row order and, within an
observation, best first; scores (C,) their similarities. Equal similarities are ordered by
landmark index (stable sort), so the result is deterministic.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from clipclique.config import MatchingConfig

FLAT = 1e-12  # a row whose largest gap is at most this has no gap at all
PARTIAL_SORT_FROM = 1024  # landmarks: from here a row's best are picked by partition before sorting


def match(similarity: np.ndarray, config: MatchingConfig) -> tuple[np.ndarray, np.ndarray]:
    """The configured strategy, then candidates at or below `config.min_similarity` dropped."""
    if config.strategy == "adaptive":
        candidates = adaptive_matches(similarity, top_m(similarity.shape[1], config.top_m_fraction))
    elif config.strategy == "knn":
        candidates = knn_matches(similarity, config.k)
    else:
        candidates = mutual_best_matches(similarity)
    scores = similarity[candidates[:, 0], candidates[:, 1]]
    keep = scores > config.min_similarity
    return candidates[keep], scores[keep]


def cap(candidates: np.ndarray, scores: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """At most `limit` candidates: the best-scored (ties by row), in their original row order;
    and whether any were dropped. A flat similarity on a map of thousands of look-alike landmarks
    would otherwise keep a quarter of the map per observation."""
    if len(candidates) <= limit:
        return candidates, scores, False
    kept = np.sort(np.argsort(-scores, kind="stable")[:limit])
    return candidates[kept], scores[kept], True


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
    return _before_largest_gap(similarity, np.ascontiguousarray(_best_first(similarity, m)))  # one compiled layout: one cache load


def knn_matches(similarity: np.ndarray, k: int) -> np.ndarray:
    """Per observation, its k most similar landmarks (all of them when the map has fewer)."""
    k = min(k, similarity.shape[1])
    if similarity.shape[0] == 0 or k == 0:
        return np.zeros((0, 2), dtype=np.int64)
    order = _best_first(similarity, k)
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
