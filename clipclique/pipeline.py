"""The localization pipeline: descriptors -> similarity -> matching -> inliers -> pose.

One function composes the stages according to a LocalizationConfig; CLIP-Clique, the baselines
(SH, X-View, CLIP-Loc) and every ablation are configurations of it (`config.METHOD_PRESETS`).
Map-side work (semantic graph, descriptors) is done once per map by `index_map`.

A frame without a pose says why in `LocalizationResult.failure`, an `outcomes.Failure` naming the
stage that lost it (its message in quotes): FEW_OBSERVATIONS "fewer than 3 observations (K)",
FEW_MATCHED "fewer than 3 observations with a candidate landmark (k)", NO_CLIQUE "no clique of 3
or more compatible correspondences", NO_MINIMAL_SET "no minimal set of 3 distinct, non-collinear
correspondences" (RANSAC/PROSAC), DEGENERATE "no correspondence set determines a pose (each is
collinear or poorly conditioned)" (every set was degenerate, or nearly a row of objects:
`config.pose.min_conditioning`), or NOT_CONFIDENT "no pose with confidence >= P (best c)"
(`min_confidence`). A bound that cut work short is `LocalizationResult.cap_hit` (`outcomes.CapHit`).

Every method's hypotheses are then verified in the image (`clipclique.verify.verification`) and given a
calibrated confidence (`clipclique.verify.confidence`) when the observations carry their boxes and camera;
`inliers.rerank` reorders them by either (verification by default), keeping the top_n best of the
`inliers.rerank_pool` hypotheses the inlier stage then fits (the heaviest cliques). Beyond the paper, by default:
each pose is refitted with every observation it brings near a similar landmark (`pose.refine_radius`,
clipclique.pose.refine), and two observations whose boxes overlap (`inliers.duplicate_iou`: one object
detected twice with two classes) never enter one clique together; adaptive matching also keeps each observation's
best landmarks of its look-alike classes (`matching.lookalike_candidates`), and with re-ranking each clique holding
such a pair is also fitted without it. Off by default, the kept hypotheses' poses can then be aligned with the
detection boxes (`pose.box_refine_steps`, clipclique.verify.boxalign). Missing CLIP embeddings make "fused" fall back
to SH only (a note says so) and make "clip" a ClipcliqueError.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.spatial import cKDTree

from clipclique.config import LocalizationConfig
from clipclique.descriptors import graph, lookalikes, matching, similarity
from clipclique.errors import ClipcliqueError
from clipclique.inliers import cliquesearch, compatibility, consensus, regions
from clipclique.inliers.cliquesearch import sort_span
from clipclique.multiframe import mapalign
from clipclique.outcomes import PIPELINE_STAGES, CapHit, Failure, FailureKind, LocalizationResult, Stage
from clipclique.pose import refine
from clipclique.pose.fit import fit_rigid_conditioned, nonzero_counts, weighted_sets
from clipclique.pose.stack import Stack
from clipclique.types import Map, Observations
from clipclique.verify import boxalign, confidence, projection, verification
from clipclique.verify.projection import pair_iou


@dataclass(kw_only=True)
class MapIndex:
    """Map-side work done once per map and config."""

    map: Map
    built_for: str  # index_key of the config this index was built with; localize checks it
    adjacency: sp.csr_matrix  # (N, N) semantic graph
    histograms: sp.csr_matrix | None  # (N, C^s) Semantic Histograms, when the descriptor uses them
    walks: sp.csr_matrix | None  # (N, C^s) X-View random-walk counts, when the descriptor uses them
    text_embeddings: np.ndarray | None = None  # (N, D) float64 copy of map.text_embeddings, made once, not per frame
    class_kernel: sp.csr_matrix | None = None  # (C, C) class similarity (lookalikes.class_kernel)
    # (N, C) the map's soft classes, when similarity.soft_classes uses them
    class_distributions: sp.csr_matrix | None = None
    histograms_by_bin: sp.csr_matrix | None = None  # (C^s, N) the histograms transposed (similarity.by_bin)
    # (C, N) class_kernel to each landmark's class (similarity.kernel_columns)
    kernel_by_landmark: np.ndarray | None = None
    capped_nodes: int = 0  # landmarks that lost neighbours to graph.max_degree
    # the map's centres, for pose refinement's nearby landmarks (refine.nearby_pairs)
    landmark_tree: cKDTree | None = None
    # landmarks by class, look-alike classes (matching.lookalike_candidates)
    class_groups: matching.ClassGroups | None = None
    spreads: np.ndarray | None = None  # (N, 9) the landmarks' spreads, verification's map side (projection.spreads)


def index_map(map: Map, config: LocalizationConfig) -> MapIndex:
    """Semantic graph and the graph descriptors `config.similarity.descriptor` needs."""
    adjacency, capped, tree = graph.capped_semantic_graph(map.ellipsoids.centers, config.graph.d_adj,
                                                          config.graph.max_degree)
    soft = (sp.csr_matrix(map.class_distributions)
            if config.similarity.soft_classes and map.class_distributions is not None else None)
    histograms, walks = _graph_descriptors(adjacency, map.class_ids, len(map.class_names), config, distributions=soft)
    text = None if map.text_embeddings is None else np.asarray(map.text_embeddings, np.float64)
    kernel = lookalikes.class_kernel(map.class_names, config.similarity.lookalike_weight)
    return MapIndex(map=map, built_for=index_key(config), adjacency=adjacency, histograms=histograms, walks=walks,
                    text_embeddings=text, class_kernel=kernel, class_distributions=soft, capped_nodes=capped,
                    histograms_by_bin=None if histograms is None else similarity.by_bin(histograms),
                    kernel_by_landmark=similarity.kernel_columns(kernel, map.class_ids),
                    landmark_tree=tree,
                    class_groups=matching.class_groups(map.class_ids, kernel, map.ellipsoids.axes),
                    spreads=projection.spreads(map.ellipsoids))


def localize(observations: Observations, index: MapIndex, config: LocalizationConfig) -> LocalizationResult:
    """Ranked camera-to-map poses for one frame's observations."""
    _check_observations(observations, index.map)
    if index.built_for != index_key(config):
        raise ClipcliqueError(
            f"the map index was built for {index.built_for}, not {index_key(config)}: call index_map with this config"
        )
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: Stage) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = timings.get(stage, 0.0) + now - clock  # a stage may run in turns
        clock = now

    histograms, walks = _query_descriptors(observations, index, config)
    lap(Stage.DESCRIPTORS)
    scores, notes = _similarity(observations, index, histograms, walks, config)
    if index.capped_nodes:
        notes.append(f"semantic graph capped: {index.capped_nodes} landmarks have more than graph.max_degree = "
                     f"{config.graph.max_degree} neighbours within d_adj; the nearest were kept")
    lap(Stage.SIMILARITY)
    candidates, candidate_scores, added = matching.match(scores, config.matching,
                                                         _lookalikes(observations, index, config))
    split = _split(observations, index.map, candidates, candidate_scores, config)
    kept = matching.best_rows(candidate_scores, config.matching.max_candidates) if split is None else split.kept
    capped = kept is not None if split is None else split.capped
    if kept is not None:
        candidates, candidate_scores, added = candidates[kept], candidate_scores[kept], added[kept]
    lap(Stage.MATCHING)

    result = LocalizationResult(hypotheses=[], candidates=candidates, candidate_scores=candidate_scores,
                                similarity=scores, num_cliques=0, cap_hit=CapHit.MAX_CANDIDATES if capped else None,
                                failure=None, notes=notes, timings=timings, lookalike_added=added)
    matched = np.count_nonzero(np.bincount(candidates[:, 0]))
    pool = _NONE
    if len(observations) < 3:
        result.failure = Failure(kind=FailureKind.FEW_OBSERVATIONS, count=len(observations))
    elif matched < 3:
        result.failure = Failure(kind=FailureKind.FEW_MATCHED, count=matched)
    elif config.inliers.method == "cliques":
        pool = _solve_cliques(result, observations, index.map, config, lap, split)
    else:
        pool = _solve_consensus(result, observations, index.map, config, lap)
    if result.failure is None and not len(pool):
        result.failure = Failure(kind=FailureKind.DEGENERATE)
    if config.pose.refine_radius > 0 and len(pool):
        pool = refine.refined(pool, observations, index.map, scores, config.pose.refine_radius, config.pose.weights,
                              landmarks=index.landmark_tree)[0]
    _verify(result, pool, observations, index, config)
    if config.pose.box_refine_steps > 0 and result.hypotheses:
        settings = config.pose
        result.hypotheses = boxalign.refined(result.hypotheses, observations, index.map, settings.box_refine_steps,
                                             settings.box_refine_scale, index.spreads, settings.box_refine_centre_m,
                                             settings.box_refine_size_weight, settings.box_refine_relative)
    lap(Stage.VERIFICATION)
    for stage in PIPELINE_STAGES:
        timings.setdefault(stage, 0.0)
    return result


def align_maps(query_map: Map, map: Map, config: LocalizationConfig) -> mapalign.MapAlignment:
    """The top transforms taking `query_map`'s coordinates into `map`'s, with their confidences and whether
    the answer is ambiguous: the query map localized as one frame (clipclique.multiframe.mapalign)."""
    query = mapalign.as_query(query_map, map, config)
    result = localize(query.observations, index_map(query.map, query.config), query.config)
    return mapalign.conclude(result, query, query_map, config)


def index_key(config: LocalizationConfig) -> str:
    """The settings a map index depends on, readable and hashable: indexes built alike share it."""
    return (f"descriptor={config.similarity.descriptor}, lookalike_weight={config.similarity.lookalike_weight}, "
            f"soft_classes={config.similarity.soft_classes}, {config.graph}")


def _graph_descriptors(
    adjacency: sp.csr_matrix,
    class_ids: np.ndarray,
    num_classes: int,
    config: LocalizationConfig,
    distributions: sp.csr_matrix | None = None,
) -> tuple[sp.csr_matrix | None, sp.csr_matrix | None]:
    """The graph descriptors of one side (X-View walks: the query's too), `distributions` the map's
    labels where it holds its own class distributions."""
    descriptor = config.similarity.descriptor
    histograms = walks = None
    if descriptor in ("fused", "sh"):
        histograms = graph.landmark_histograms(adjacency, class_ids, num_classes, config.graph.walk_length,
                                               distributions)
    if descriptor == "xview":
        rng = np.random.default_rng(config.graph.xview_seed)
        walks = graph.random_walk_descriptors(
            adjacency, class_ids, num_classes, config.graph.walk_length, config.graph.xview_walks, rng
        )
    return histograms, walks


def _query_descriptors(
    observations: Observations, index: MapIndex, config: LocalizationConfig
) -> tuple[graph.SparseRows | None, sp.csr_matrix | None]:
    """The query side's graph descriptors, its labels softened by the class kernel when
    `similarity.lookalike_weight` > 0; Semantic Histograms by the compiled `graph.query_histograms`."""
    soft = index.class_kernel if config.similarity.lookalike_weight > 0 else None
    centers, num_classes = observations.ellipsoids.centers, len(index.map.class_names)
    if config.similarity.descriptor in ("fused", "sh"):
        histograms = graph.query_histograms(centers, observations.class_ids, num_classes, config.graph.d_adj,
                                            config.graph.max_degree, config.graph.walk_length, soft)
        return histograms, None
    if config.similarity.descriptor != "xview":
        return None, None  # CLIP alone reads no graph
    query_graph = graph.semantic_graph(centers, config.graph.d_adj, config.graph.max_degree)
    return _graph_descriptors(query_graph, observations.class_ids, num_classes, config)


def _similarity(
    observations: Observations,
    index: MapIndex,
    histograms: graph.SparseRows | None,
    walks: sp.csr_matrix | None,
    config: LocalizationConfig,
) -> tuple[np.ndarray, list[str]]:
    descriptor = config.similarity.descriptor
    if descriptor == "xview":
        return similarity.walk_similarity(walks, index.walks), []
    if descriptor == "sh":
        return _histogram_similarity(observations, index, histograms, config), []
    missing = _missing_embeddings(observations, index.map)
    if descriptor == "clip":
        if missing:
            raise ClipcliqueError(f"descriptor 'clip' needs CLIP embeddings, but {missing}")
        return similarity.clip_similarity(observations.image_embeddings, index.text_embeddings), []
    sh = _histogram_similarity(observations, index, histograms, config)
    if missing:
        return sh, [f"no CLIP embeddings ({missing}): alpha = 0 (SH only)"]
    clip = similarity.clip_similarity(observations.image_embeddings, index.text_embeddings)
    return similarity.fuse(clip, sh, config.similarity.alpha), []


def _histogram_similarity(
    observations: Observations, index: MapIndex, histograms: graph.SparseRows, config: LocalizationConfig
) -> np.ndarray:
    """S_sh, with the class term when `similarity.class_weight` > 0."""
    sh = similarity.histogram_similarity(histograms, index.histograms_by_bin)
    weight = config.similarity.class_weight
    if weight == 0:
        return sh
    if index.class_distributions is not None:
        classes = similarity.soft_class_similarity(observations.class_ids, index.class_kernel,
                                                   index.class_distributions)
        return similarity.with_class_term(sh, classes, np.arange(len(classes)), weight)
    return similarity.with_class_term(sh, index.kernel_by_landmark, observations.class_ids, weight)


def _lookalikes(observations: Observations, index: MapIndex, config: LocalizationConfig) -> matching.Lookalikes | None:
    """What `matching.lookalike_candidates` needs of this query; None when that is off."""
    settings = config.matching
    if (settings.strategy != "adaptive" or settings.lookalike_candidates == 0 or config.similarity.lookalike_weight == 0
            or index.class_groups is None):
        return None
    return matching.Lookalikes(groups=index.class_groups, classes=observations.class_ids,
                               axes=np.sort(np.asarray(observations.ellipsoids.axes, np.float64), axis=1))


def _missing_embeddings(observations: Observations, map: Map) -> str | None:
    """Why CLIP similarity cannot be computed, or None when it can."""
    if map.text_embeddings is None:
        return "the map has no text embeddings"
    if observations.image_embeddings is None:
        return "the observations have no image embeddings"
    if observations.image_embeddings.shape[1] != map.text_embeddings.shape[1]:
        raise ClipcliqueError(
            f"image embeddings have {observations.image_embeddings.shape[1]} dimensions but the map's text "
            f"embeddings ({map.encoder}) have {map.text_embeddings.shape[1]}: use the encoder that built the map"
        )
    return None


def _check_observations(observations: Observations, map: Map) -> None:
    """Class ids the map has, and finite ellipsoids: one NaN centre made every pair distance's maximum NaN, so
    that no pair of the frame passed compatibility (a silent failure), and a KD-tree refused it outright."""
    shapes = observations.ellipsoids
    if _valid(observations.class_ids, len(map.class_names), shapes.centers, shapes.axes, shapes.rotations):
        return
    ids = observations.class_ids
    if len(ids) and (ids.min() < 0 or ids.max() >= len(map.class_names)):
        raise ClipcliqueError(
            f"observation class ids must index the map's {len(map.class_names)} classes; got {ids.min()}..{ids.max()}"
        )
    if np.isfinite(shapes.centers).all() and np.isfinite(shapes.axes).all() and np.isfinite(shapes.rotations).all():
        return
    rows = {int(row) for part in (shapes.centers, shapes.axes, shapes.rotations)
            for row in np.flatnonzero(~np.isfinite(part.reshape(len(part), -1)).all(axis=1))}
    raise ClipcliqueError(f"observation {min(rows)} has a centre, axes or rotation that is not finite "
                          f"({len(rows)} of {len(observations)} observations)")


@njit(cache=True)
def _valid(class_ids: np.ndarray, num_classes: int, centers: np.ndarray, axes: np.ndarray,
           rotations: np.ndarray) -> bool:
    """Whether `_check_observations` passes: one compiled pass where its min, max and three finite tests were
    some ten numpy calls a query (its numpy code then only explains a failure)."""
    for class_id in class_ids:
        if class_id < 0 or class_id >= num_classes:
            return False
    return _finite(centers) and _finite(axes) and _finite(rotations)


@njit(cache=True, inline="always")
def _finite(values: np.ndarray) -> bool:
    for value in values.flat:
        if not np.isfinite(value):
            return False
    return True


def _split(observations: Observations, map: Map, candidates: np.ndarray, scores: np.ndarray,
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


def _solve_cliques(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig,
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
        slack = compatibility.partial_view_slack(  # take: a row gather, quicker than fancy indexing
            observations.ellipsoids.axes.take(candidates[:, 0], axis=0),
            map.ellipsoids.axes.take(candidates[:, 1], axis=0),
            settings.partial_slack, settings.max_slack, settings.slack_min_deficit,
        )
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
    if _reranked(observations, config) and result.lookalike_added is not None and result.lookalike_added.any():
        members, sizes, totals = _without_added(*found.stacked(), result.lookalike_added, scores,
                                                settings.min_clique_size)
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
    return max(config.top_n, config.inliers.rerank_pool) if _reranked(observations, config) else config.top_n


def _reranked(observations: Observations, config: LocalizationConfig) -> bool:
    """Whether the hypotheses will be re-ranked in the image (`inliers.rerank`, boxes and camera given)."""
    return config.inliers.rerank != "none" and observations.boxes is not None and observations.camera is not None


def _stacked(sets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
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
    objects = np.arange(len(observations))
    if duplicate_iou == 0 or observations.boxes is None or len(observations) < 2:
        return objects
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


def _solve_consensus(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig,
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
    pool = _hypotheses(result, observations, map, config, *_stacked(found.inlier_sets), np.array(found.scores))
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
        return _NONE
    pairs = result.candidates.take(members, axis=0)  # take: a row gather, a fifth of fancy indexing's time
    # Shorter sets are padded with the first candidate at weight 0, its numbers as Python's (numba's dispatch reads
    # a numpy scalar argument microseconds slower).
    first = result.candidates[0].tolist()
    source, target, weights = weighted_sets(
        pairs, result.candidate_scores[members], sizes, (first[0], first[1], result.candidate_scores[0]),
        (observations.ellipsoids.centers, observations.ellipsoids.axes), (map.ellipsoids.centers, map.ellipsoids.axes),
        config.pose.weights)
    rotation, translation, ok, measure = fit_rigid_conditioned(source, target, weights)
    if _usable(ok, weights, measure, float(config.pose.min_conditioning)):  # nearly always: the arrays as they are
        return Stack(rotations=rotation, translations=translation, pairs=pairs,
                     counts=sizes.astype(np.int64, copy=False), scores=np.asarray(scores, np.float64),
                     conditioning=measure)
    return Stack(rotations=rotation[ok], translations=translation[ok], pairs=pairs[np.repeat(ok, sizes)],
                 counts=sizes[ok].astype(np.int64), scores=np.asarray(scores, np.float64)[ok], conditioning=measure[ok])


_NONE = Stack.of([])  # no hypothesis
# Re-ranking keys equal to this many decimals tie, and ties keep the pool's order (the clique score's): the same
# correspondences in another order fit a pose that differs in its last bits, and so does its verification score.
RANK_DECIMALS = 9


@njit(cache=True)
def _usable(ok: np.ndarray, weights: np.ndarray, measure: np.ndarray, min_conditioning: float) -> bool:
    """`ok &= (nonzero_counts(weights) >= 3) & (measure >= min_conditioning)` in place (else too few weighted
    pairs, or a near-row of objects), and whether all are: one call for numpy's five passes over a batch's rows."""
    counts = nonzero_counts(weights)
    usable = True
    for b in range(len(ok)):
        ok[b] = ok[b] and counts[b] >= 3 and measure[b] >= min_conditioning
        usable &= ok[b]
    return usable


def _verify(result: LocalizationResult, pool: Stack, observations: Observations, index: MapIndex,
            config: LocalizationConfig) -> None:
    """Verification score and confidence of every hypothesis of the pool, then `inliers.rerank` and
    `min_confidence`: `result.hypotheses`, the kept ones built from the stack.

    Observations without boxes and camera (a library caller's own) are left unverified and in the
    clique score's order (a note says so), unless a confidence floor asks for verification.
    """
    if observations.boxes is None or observations.camera is None:
        if config.min_confidence > 0:
            verification.require_image(observations, "min_confidence")
        if config.inliers.rerank != "none" and len(pool):
            result.notes.append(f"no boxes or camera: inliers.rerank = {config.inliers.rerank} not applied")
        result.hypotheses = pool.hypotheses()
        return
    if not len(pool):
        return
    seen, narrowed, similarity_seen = _with_boxes(observations, pool, result.similarity)
    checked = verification.verify_stack(narrowed, seen, index.map, config.verification, index.spreads)
    model = confidence.load_model(config.confidence_model)
    probability = (None if model is None else
                   model.predict(confidence.Evidence(narrowed, checked, similarity_seen, len(seen))))
    kept = None
    if config.inliers.rerank != "none":
        if config.inliers.rerank == "confidence" and probability is None:
            raise ClipcliqueError(
                "inliers.rerank = confidence needs a confidence model (none is shipped in this build)")
        key = checked.score if config.inliers.rerank == "verification" else probability
        kept = np.argsort(-np.round(key, RANK_DECIMALS), kind="stable")[: config.top_n]
    result.hypotheses = pool.hypotheses(kept, checked.score, probability)
    if config.min_confidence > 0:
        if probability is None:
            raise ClipcliqueError("min_confidence needs a confidence model (none is shipped in this build)")
        best = max(h.confidence for h in result.hypotheses)
        result.hypotheses = [h for h in result.hypotheses if h.confidence >= config.min_confidence]
        if not result.hypotheses:
            result.failure = Failure(kind=FailureKind.NOT_CONFIDENT, min_confidence=config.min_confidence,
                                     best_confidence=best)


def _with_boxes(observations: Observations, pool: Stack,
                similarity: np.ndarray) -> tuple[Observations, Stack, np.ndarray]:
    """What verification and confidence may read: the observations with a box in the query image, each
    hypothesis with its correspondences among them (renumbered), and their rows of the similarity.
    Unchanged when every observation has a box (a single frame)."""
    if observations.has_box is None or observations.has_box.all():
        return observations, pool, similarity
    kept = np.flatnonzero(observations.has_box)
    renumber = np.full(len(observations), -1)
    renumber[kept] = np.arange(len(kept))
    boxed = observations.has_box[pool.pairs[:, 0]]
    pairs = pool.pairs[boxed]
    narrowed = replace(pool, pairs=np.column_stack((renumber[pairs[:, 0]], pairs[:, 1])),
                       counts=np.bincount(pool.owners()[boxed], minlength=len(pool)))
    return observations.subset(kept), narrowed, similarity[kept]
