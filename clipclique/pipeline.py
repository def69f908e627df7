"""The localization pipeline: descriptors -> similarity -> matching -> inliers -> pose.

One function composes the stages according to a LocalizationConfig; CLIP-Clique, the baselines
(SH, X-View, CLIP-Loc) and every ablation are configurations of it (`config.METHOD_PRESETS`).
Map-side work (semantic graph, descriptors) is done once per map by `index_map`. Each stage's own wiring
lives in its room: the query's descriptors and similarity in clipclique.descriptors.query, the inlier
stage's (cliques or a consensus -> a Stack of poses) in clipclique.inliers.hypotheses, verification's
(verify, confidence, re-rank, min_confidence) in clipclique.verify.ranking.

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
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.spatial import cKDTree

from clipclique.config import LocalizationConfig
from clipclique.descriptors import graph, lookalikes, matching, query, similarity
from clipclique.errors import ClipcliqueError
from clipclique.inliers import hypotheses
from clipclique.multiframe import mapalign
from clipclique.outcomes import PIPELINE_STAGES, CapHit, Failure, FailureKind, LocalizationResult, Stage
from clipclique.pose import refine
from clipclique.types import Map, Observations
from clipclique.verify import boxalign, projection, ranking


@dataclass(kw_only=True)
class MapIndex:
    """Map-side work done once per map and config."""

    map: Map
    built_for: str  # index_key of the config this index was built with
    settings: tuple  # _index_settings of that config: what localize compares (formatting the key cost 1.3 us a query)
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
    histograms, walks = query.graph_descriptors(adjacency, map.class_ids, len(map.class_names), config,
                                                distributions=soft)
    text = None if map.text_embeddings is None else np.asarray(map.text_embeddings, np.float64)
    kernel = lookalikes.class_kernel(map.class_names, config.similarity.lookalike_weight)
    return MapIndex(map=map, built_for=index_key(config), settings=_index_settings(config), adjacency=adjacency,
                    histograms=histograms, walks=walks, text_embeddings=text, class_kernel=kernel,
                    class_distributions=soft, capped_nodes=capped,
                    histograms_by_bin=None if histograms is None else similarity.by_bin(histograms),
                    kernel_by_landmark=similarity.kernel_columns(kernel, map.class_ids),
                    landmark_tree=tree,
                    class_groups=matching.class_groups(map.class_ids, kernel, map.ellipsoids.axes),
                    spreads=projection.spreads(map.ellipsoids))


def localize(observations: Observations, index: MapIndex, config: LocalizationConfig) -> LocalizationResult:
    """Ranked camera-to-map poses for one frame's observations."""
    _check_observations(observations, index.map)
    if index.settings != _index_settings(config):
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

    histograms, walks = query.descriptors(observations, index, config)
    lap(Stage.DESCRIPTORS)
    scores, notes = query.scores(observations, index, histograms, walks, config)
    if index.capped_nodes:
        notes.append(f"semantic graph capped: {index.capped_nodes} landmarks have more than graph.max_degree = "
                     f"{config.graph.max_degree} neighbours within d_adj; the nearest were kept")
    lap(Stage.SIMILARITY)
    candidates, candidate_scores, added = matching.match(scores, config.matching,
                                                         query.lookalikes(observations, index, config))
    split = hypotheses.split_regions(observations, index.map, candidates, candidate_scores, config)
    kept = matching.best_rows(candidate_scores, config.matching.max_candidates) if split is None else split.kept
    capped = kept is not None if split is None else split.capped
    if kept is not None:
        candidates, candidate_scores, added = candidates[kept], candidate_scores[kept], added[kept]
    lap(Stage.MATCHING)

    result = LocalizationResult(hypotheses=[], candidates=candidates, candidate_scores=candidate_scores,
                                similarity=scores, num_cliques=0, cap_hit=CapHit.MAX_CANDIDATES if capped else None,
                                failure=None, notes=notes, timings=timings, lookalike_added=added)
    matched = np.count_nonzero(np.bincount(candidates[:, 0]))
    pool = hypotheses.NONE
    if len(observations) < 3:
        result.failure = Failure(kind=FailureKind.FEW_OBSERVATIONS, count=len(observations))
    elif matched < 3:
        result.failure = Failure(kind=FailureKind.FEW_MATCHED, count=matched)
    elif config.inliers.method == "cliques":
        pool = hypotheses.from_cliques(result, observations, index.map, config, lap, split)
    else:
        pool = hypotheses.from_consensus(result, observations, index.map, config, lap)
    if result.failure is None and not len(pool):
        result.failure = Failure(kind=FailureKind.DEGENERATE)
    if config.pose.refine_radius > 0 and len(pool):
        pool = refine.refine_stack(pool, observations, index.map, scores, config.pose.refine_radius,
                                   config.pose.weights, landmarks=index.landmark_tree)[0]
    ranking.verify_pool(result, pool, observations, index.map, index.spreads, config)
    if config.pose.box_refine_steps > 0 and result.hypotheses:
        settings = config.pose
        result.hypotheses = boxalign.refine_hypotheses(result.hypotheses, observations, index.map,
                                                       settings.box_refine_steps, settings.box_refine_scale,
                                                       index.spreads, settings.box_refine_centre_m,
                                                       settings.box_refine_size_weight, settings.box_refine_relative)
    lap(Stage.VERIFICATION)
    for stage in PIPELINE_STAGES:
        timings.setdefault(stage, 0.0)
    return result


def align_maps(query_map: Map, map: Map, config: LocalizationConfig) -> mapalign.MapAlignment:
    """The top transforms taking `query_map`'s coordinates into `map`'s, with their confidences and whether
    the answer is ambiguous: the query map localized as one frame (clipclique.multiframe.mapalign)."""
    frame = mapalign.as_query(query_map, map, config)  # (`query` is the descriptor stage's module)
    result = localize(frame.observations, index_map(frame.map, frame.config), frame.config)
    return mapalign.conclude(result, frame, query_map, config)


def index_key(config: LocalizationConfig) -> str:
    """The settings a map index depends on, readable and hashable: indexes built alike share it."""
    return (f"descriptor={config.similarity.descriptor}, lookalike_weight={config.similarity.lookalike_weight}, "
            f"soft_classes={config.similarity.soft_classes}, {config.graph}")


def _index_settings(config: LocalizationConfig) -> tuple:
    """The values `index_key` reads, as a tuple: compared in a fraction of the time its string takes to format."""
    settings = config.similarity
    return settings.descriptor, settings.lookalike_weight, settings.soft_classes, *vars(config.graph).values()


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
