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


def match(similarity: np.ndarray, config: MatchingConfig, lookalike: np.ndarray | None = None,
          landmark_classes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The configured strategy, then candidates at or below `config.min_similarity` dropped: the candidates,
    their scores, and (C,) which of them only `with_lookalikes` added.

    Adaptive matching also keeps, per observation, its `config.lookalike_candidates` most similar
    landmarks of each class `lookalike` (K, N) marks as one its detector confuses with its own
    (`landmark_classes` (N,) groups them)."""
    added = None
    if config.strategy == "adaptive":
        candidates = adaptive_matches(similarity, top_m(similarity.shape[1], config.top_m_fraction))
        if config.lookalike_candidates and lookalike is not None and landmark_classes is not None:
            candidates, added = with_lookalikes(candidates, similarity, lookalike, landmark_classes,
                                                config.lookalike_candidates)
    elif config.strategy == "knn":
        candidates = knn_matches(similarity, config.k)
    else:
        candidates = mutual_best_matches(similarity)
    added = np.zeros(len(candidates), bool) if added is None else added
    scores = similarity[candidates[:, 0], candidates[:, 1]]
    keep = scores > config.min_similarity
    return candidates[keep], scores[keep], added[keep]


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
    return _before_largest_gap(similarity, np.ascontiguousarray(_best_first(similarity, m)))  # one compiled layout: one cache load


def with_lookalikes(candidates: np.ndarray, similarity: np.ndarray, lookalike: np.ndarray,
                    landmark_classes: np.ndarray, per_class: int) -> tuple[np.ndarray, np.ndarray]:
    """`candidates` plus each observation's `per_class` most similar landmarks of every class marked in its row
    of `lookalike` (K, N), in the candidates' order (by observation, best first, ties by landmark index), and
    (C,) which of them were added.

    A detection of a cup labelled "bottle" matches the map's bottles far better than its cups (the class
    term), so the largest similarity gap falls between the two classes and the right cup is never a
    candidate: on a cluttered desk four in five such detections lost their landmark so. Its best cups
    (by their neighbourhoods) come back as lighter candidates; a clique still needs them to agree."""
    rows, columns = np.nonzero(lookalike)
    if per_class == 0 or len(rows) == 0:
        return candidates, np.zeros(len(candidates), bool)
    values = similarity[rows, columns]
    order = np.lexsort((columns, -values, landmark_classes[columns], rows))  # by row, class, best first
    rows, columns, classes = rows[order], columns[order], landmark_classes[columns[order]]
    group = np.r_[True, (rows[1:] != rows[:-1]) | (classes[1:] != classes[:-1])]
    starts = np.flatnonzero(group)
    rank = np.arange(len(rows)) - np.repeat(starts, np.diff(np.r_[starts, len(rows)]))
    added = np.column_stack((rows[rank < per_class], columns[rank < per_class])).astype(np.int64)
    merged = np.unique(np.concatenate((candidates, added)), axis=0)
    scores = similarity[merged[:, 0], merged[:, 1]]
    merged = merged[np.lexsort((merged[:, 1], -scores, merged[:, 0]))]
    kept = np.zeros(similarity.shape, bool)
    kept[candidates[:, 0], candidates[:, 1]] = True
    return merged, ~kept[merged[:, 0], merged[:, 1]]


def similar_in_size(pairs: np.ndarray, observed_axes: np.ndarray, landmark_axes: np.ndarray, ratio: float) -> np.ndarray:
    """`pairs` (K, N) bool, cleared where the observation's sorted semi-axes (K, 3) and the landmark's (N, 3)
    differ by more than `ratio` on some axis: of the added look-alike candidates on a cluttered desk the right
    ones differ by a median factor of 1.3, the wrong ones by 2.1 (a cup is not a bowl's size)."""
    rows, columns = np.nonzero(pairs)
    observed = np.sort(observed_axes, axis=1)[rows]
    mapped = np.sort(landmark_axes, axis=1)[columns]
    apart = (np.maximum(observed, mapped) > ratio * np.minimum(observed, mapped)).any(axis=1)
    kept = pairs.copy()
    kept[rows[apart], columns[apart]] = False
    return kept


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
