"""What the inlier stage hands on: a frame's candidates, split by map region where that pays, turned into a Stack
of hypotheses, one weighted pose per heaviest clique of the compatibility graph (`from_cliques`) or per
RANSAC/PROSAC inlier set (`from_consensus`).

It exists so that `clipclique.pipeline` stays the composition of the stages: the search modules
(compatibility, cliquesearch, regions, consensus) find correspondence sets, and this one wires them to the
pose fits (clipclique.pose.fit) with the inlier stage's own post-processing: the pool size re-ranking asks for
(clipclique.verify.ranking), more cliques where some are degenerate, cliques without their added look-alike
pairs, and one object detected twice (overlapping boxes) kept out of one clique.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit

from clipclique.config import LocalizationConfig
from clipclique.inliers import cliquesearch, compatibility, consensus, regions
from clipclique.inliers.cliquesearch import sort_span
from clipclique.outcomes import CapHit, Failure, FailureKind, LocalizationResult, Stage
from clipclique.pose.fit import fit_sets
from clipclique.pose.stack import Stack
from clipclique.types import Map, Observations
from clipclique.verify import verification
from clipclique.verify.projection import pair_iou
from clipclique.verify.ranking import reranked

NONE = Stack.of([])  # no hypothesis


def split_regions(observations: Observations, map: Map, candidates: np.ndarray, scores: np.ndarray,
                  config: LocalizationConfig) -> regions.Regions | None:
    """The candidates split by map region (clipclique.inliers.regions) when a clique search has at least
    inliers.region_split_from of them (or more than matching.max_candidates) in more than one region and
    at most half as many distinct layouts as regions; None otherwise (the whole frame is searched, capped).
    The split pays only through copies searched once: a region searched on its own costs its own graph
    and search, and a building of a hundred rooms that differ by a centimetre took three times as long
    region by region as in one search (1,000 rooms: over a second, where the capped search takes 85 ms)."""
    split_from = min(config.inliers.region_split_from, config.matching.max_candidates + 1)
    if len(candidates) < split_from or config.inliers.method != "cliques":
        return None
    split = regions.split(observations.ellipsoids.centers, map.ellipsoids, candidates, scores,
                          _objects(observations, config.inliers.duplicate_iou), config.inliers,
                          config.matching.max_candidates)
    return split if len(split.rows) > 1 and 2 * len(split.copies) <= len(split.rows) else None


def from_cliques(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig,
                 lap: Callable[[Stage], None], split: regions.Regions | None = None) -> Stack:
    """The heaviest maximal cliques of the compatibility graph (summed similarity), one pose each (the
    pool, stacked); on a map of many candidates in several regions (`split`), region by region
    (clipclique.inliers.regions).

    A degenerate clique gives no pose; the search is then asked for twice as many cliques
    until top_n poses are found or the cliques run out (the first ones come back unchanged).
    """
    settings = config.inliers
    candidates, scores = result.candidates, result.candidate_scores
    centers = observations.ellipsoids.centers, map.ellipsoids.centers
    objects = _objects(observations, settings.duplicate_iou)
    if split is None:
        slack = compatibility.candidate_slack(observations.ellipsoids.axes, map.ellipsoids.axes, candidates,
                                              settings.partial_slack, settings.max_slack, settings.slack_min_deficit)
        kept = compatibility.affordable_candidates(*centers, candidates, scores, settings.d_comp, slack,
                                                   max_pairs=settings.max_pairs)
        pairs_capped = len(kept) < len(candidates)
        if pairs_capped:
            edges = kept[compatibility.compatibility_graph(*centers, candidates[kept], settings.d_comp, slack[kept],
                                                           objects)]
        else:  # all kept: no copies
            edges = compatibility.compatibility_graph(*centers, candidates, settings.d_comp, slack, objects)

        def search(wanted: int) -> cliquesearch.TopCliques:
            return cliquesearch.top_cliques(edges, len(candidates), scores, wanted, objects[candidates[:, 0]],
                                            settings.min_clique_size, settings.max_cliques, settings.time_limit_s)
    else:
        layouts, pairs_capped = regions.layouts(split, observations.ellipsoids, map.ellipsoids, candidates, scores,
                                                objects, settings)

        def search(wanted: int) -> cliquesearch.TopCliques:
            return regions.top_cliques(layouts, wanted, settings)
    if pairs_capped:
        result.cap_hit = result.cap_hit or CapHit.MAX_PAIRS
    pool = _pool_size(observations, config)
    wanted, tried, fits, fitted = pool, 0, [], 0
    while True:
        found = search(wanted)
        lap(Stage.INLIERS)
        fit = _hypotheses(result, observations, map, config, *found.stacked(tried), found.totals[tried:])
        fits.append(fit if len(fit) <= pool - fitted else fit.take(np.arange(pool - fitted)))
        fitted += len(fits[-1])
        lap(Stage.POSE)
        tried = len(found.sizes)
        if fitted == pool or tried < wanted or found.cap is not None:
            break
        wanted *= 2
    cliques, added = found.stacked(), result.lookalike_added
    if reranked(observations, config) and added is not None and _holds_rest(*cliques, added,
                                                                             settings.min_clique_size):
        members, sizes, totals = _without_added(*cliques, added, scores, settings.min_clique_size)
        if len(sizes):  # else no stack to join: the pool as it is
            fits.append(_hypotheses(result, observations, map, config, members, sizes, totals))
    result.num_cliques = found.reached
    result.cap_hit = result.cap_hit or found.cap
    if split is not None:
        result.region_split = regions.summary(split, layouts, found)
        if result.region_split.ambiguous:
            result.notes.append(f"ambiguous: the best clique fits {result.region_split.tied_regions} identical map "
                                f"regions equally well (of {result.region_split.regions} searched one by one)")
    if not len(found.sizes):
        result.failure = Failure(kind=FailureKind.NO_CLIQUE, count=settings.min_clique_size)
    return Stack.joined(fits)


def _pool_size(observations: Observations, config: LocalizationConfig) -> int:
    """Hypotheses the inlier stage fits: `inliers.rerank_pool` (at least top_n) when they will be re-ranked in
    the image (verification keeps the top_n), else top_n."""
    return max(config.top_n, config.inliers.rerank_pool) if reranked(observations, config) else config.top_n


def _flatten_sets(sets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Sets of candidates as one array of their members, set after set, and (B,) their sizes."""
    return (np.concatenate(sets).astype(np.int64) if sets else np.zeros(0, np.int64),
            np.array([len(members) for members in sets], np.int64))


def _without_added(members: np.ndarray, sizes: np.ndarray, added: np.ndarray, scores: np.ndarray,
                   min_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each clique (of `members`, clique after clique, `sizes[c]` each) holding candidates only
    `matching.lookalike_candidates` added, without them, where at least `min_size` remain and neither a clique nor
    an earlier such set is that set already, in the cliques' order: their members (in each clique's order), sizes,
    stacked alike, and totals (the sum of each one's float64 `scores`).

    An added look-alike pair may complete a clique (the right one where a cup was detected as "bottle"), but
    as a maximal clique it also replaces the clique without it, whose pose was often the more precise one on
    a cluttered desk: verification chooses between both."""
    return _rests(np.asarray(members, np.int64), np.asarray(sizes, np.int64), np.asarray(added, np.bool_),
                  np.asarray(scores, np.float64), min_size)


@njit(cache=True)
def _holds_rest(members: np.ndarray, sizes: np.ndarray, added: np.ndarray, min_size: int) -> bool:
    """Whether some clique holds a candidate `added` and at least `min_size` others: where none does,
    `_without_added` has no set to give (most frames of a room: its added pairs are in no clique, or in a clique of
    three, whose rest is too small), and one answer costs less than its arrays handed back empty."""
    start = 0
    for c in range(len(sizes)):
        kept = 0
        for i in range(start, start + sizes[c]):
            kept += not added[members[i]]
        if min_size <= kept < sizes[c]:
            return True
        start += sizes[c]
    return False


@njit(cache=True)
def _rests(members: np.ndarray, sizes: np.ndarray, added: np.ndarray, scores: np.ndarray,
           min_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`_without_added` in one compiled pass, instead of a dozen numpy passes (lexsort, bincounts, repeats) on a
    frame's few cliques: each clique's members sorted, each eligible rest (sorted) kept unless a clique of its size or
    an eligible rest before it holds the same numbers (only the rests compared: grouping every set with every other,
    a desk frame's fifty overlapping cliques among them, took most of the pass), and the kept rests' score totals."""
    count = len(sizes)
    starts = np.cumsum(sizes) - sizes
    rest_sizes = np.zeros(count, np.int64)
    for c in range(count):
        for i in range(starts[c], starts[c] + sizes[c]):
            rest_sizes[c] += not added[members[i]]
    eligible = (rest_sizes >= min_size) & (rest_sizes < sizes)
    sets = np.empty(len(members) + rest_sizes[eligible].sum(), np.int64)  # the cliques, then the rests, each sorted
    rest_starts = np.empty(count, np.int64)
    at = len(members)
    for c in range(count):
        start = starts[c]
        for i in range(start, start + sizes[c]):
            sets[i] = members[i]
        sort_span(sets, start, start + sizes[c])
        rest_starts[c] = at
        for i in range(start, start + sizes[c] if eligible[c] else start):
            if not added[sets[i]]:
                sets[at] = sets[i]
                at += 1
    kept = eligible.copy()
    for c in np.flatnonzero(eligible):
        for d in range(count):
            if (sizes[d] == rest_sizes[c] and _same_span(sets, starts[d], rest_starts[c], rest_sizes[c])) or (
                    d < c and eligible[d] and rest_sizes[d] == rest_sizes[c]
                    and _same_span(sets, rest_starts[d], rest_starts[c], rest_sizes[c])):
                kept[c] = False
                break
    kept_members, kept_scores = np.empty(rest_sizes[kept].sum(), np.int64), np.empty(rest_sizes[kept].sum())
    totals = np.empty(kept.sum())
    at = 0
    for b, c in enumerate(np.flatnonzero(kept)):
        total = 0.0
        for i in range(starts[c], starts[c] + sizes[c]):
            if not added[members[i]]:
                kept_members[at], kept_scores[at] = members[i], scores[members[i]]
                total += kept_scores[at]
                at += 1
        totals[b] = total
    return kept_members, rest_sizes[kept], totals


@njit(cache=True, inline="always")
def _same_span(values: np.ndarray, first: int, second: int, size: int) -> bool:
    """Whether values[first: first + size] and values[second: second + size] hold the same numbers in order, read
    by index (a view is reference-counted)."""
    for i in range(size):
        if values[first + i] != values[second + i]:
            return False
    return True


def _objects(observations: Observations, duplicate_iou: float) -> np.ndarray:
    """(K,) the object each observation shows: its own index, or with `duplicate_iou` > 0 the first
    of the observations whose boxes overlap it at least that much (one object detected twice)."""
    if duplicate_iou == 0 or observations.boxes is None or len(observations) < 2:
        return np.arange(len(observations))
    return _first_overlapping(np.ascontiguousarray(observations.boxes, np.float64), duplicate_iou)


@njit(cache=True)
def _first_overlapping(boxes: np.ndarray, duplicate_iou: float) -> np.ndarray:
    """`_objects` of boxes (K, 4): in order, so that the earlier observation's object is settled."""
    objects = np.arange(len(boxes))
    for k in range(len(boxes)):
        for j in range(k):
            if pair_iou(boxes[k], boxes[j]) >= duplicate_iou:
                objects[k] = objects[j]
                break
    return objects


def from_consensus(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig,
                   lap: Callable[[Stage], None]) -> Stack:
    """RANSAC / PROSAC inlier sets, each refit with the weighted pose (the pool, stacked)."""
    settings = config.inliers
    obs, lm = result.candidates[:, 0], result.candidates[:, 1]
    image = None
    if settings.verification == "overlap":
        verification.require_image(observations, "inliers.verification = overlap (set it to centers otherwise)")
        image = consensus.ImageEvidence(map.ellipsoids, observations.boxes, observations.camera, settings.iou_threshold)
    found = consensus.sample_consensus(
        observations.ellipsoids.centers,
        map.ellipsoids.centers,
        result.candidates,
        result.candidate_scores,
        iterations=settings.ransac_iterations,
        threshold=settings.inlier_threshold,
        rng=np.random.default_rng(settings.seed),
        progressive=settings.method == "prosac",
        same_class=observations.class_ids[obs] == map.class_ids[lm],
        keep=_pool_size(observations, config),
        image=image,
    )
    result.num_cliques = found.num_hypotheses
    lap(Stage.INLIERS)
    pool = _hypotheses(result, observations, map, config, *_flatten_sets(found.inlier_sets), np.array(found.scores))
    if not found.inlier_sets:
        result.failure = Failure(kind=FailureKind.NO_MINIMAL_SET)
    lap(Stage.POSE)
    return pool


def _hypotheses(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig,
                members: np.ndarray, sizes: np.ndarray, scores: np.ndarray) -> Stack:
    """The weighted pose of each correspondence set (of candidates `members`, set after set, `sizes[b]` each), in
    order, fitted in one batch (shorter sets padded with weight 0). A degenerate set (collinear, fewer than 3
    positive weights) or one too poorly conditioned to fix the rotation (config.pose.min_conditioning) gives none."""
    if not len(sizes):
        return NONE
    pairs = result.candidates.take(members, axis=0)  # take: a row gather, a fifth of fancy indexing's time
    # Shorter sets are padded with the first candidate at weight 0, its numbers as Python's (numba's dispatch reads
    # a numpy scalar argument microseconds slower).
    first = result.candidates[0].tolist()
    rotation, translation, ok, measure, usable = fit_sets(
        pairs, result.candidate_scores[members], sizes, (first[0], first[1], result.candidate_scores[0]),
        (observations.ellipsoids.centers, observations.ellipsoids.axes), (map.ellipsoids.centers, map.ellipsoids.axes),
        config.pose.weights, config.pose.min_conditioning)
    if usable:  # nearly always: the arrays as they are
        return Stack(rotations=rotation, translations=translation, pairs=pairs,
                     counts=sizes.astype(np.int64, copy=False), scores=np.asarray(scores, np.float64),
                     conditioning=measure)
    return Stack(rotations=rotation[ok], translations=translation[ok], pairs=pairs[np.repeat(ok, sizes)],
                 counts=sizes[ok].astype(np.int64), scores=np.asarray(scores, np.float64)[ok], conditioning=measure[ok])
