"""The localization pipeline: descriptors -> similarity -> matching -> inliers -> pose.

One function composes the stages according to a LocalizationConfig; CLIP-Clique, the baselines
(SH, X-View, CLIP-Loc) and every ablation are configurations of it (`config.METHOD_PRESETS`).
Map-side work (semantic graph, descriptors) is done once per map by `index_map`.

A frame without a pose says why in `LocalizationResult.failure`, naming the stage that lost it:
"fewer than 3 observations (K)", "fewer than 3 observations with a candidate landmark (k)",
"no clique of 3 or more compatible correspondences", "no minimal set of 3 distinct,
non-collinear correspondences" (RANSAC/PROSAC), "no correspondence set determines a pose"
(every set was degenerate), or "no pose with confidence >= P (best c)" (`min_confidence`).

Every method's hypotheses are then verified in the image (`clipclique.verification`) and given a
calibrated confidence (`clipclique.confidence`) when the observations carry their boxes and camera;
`inliers.rerank` reorders them by either. Missing CLIP embeddings make "fused" fall back to SH only (a note
says so) and make "clip" a ClipcliqueError.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from clipclique import confidence, graph, inliers, matching, similarity, verification
from clipclique.config import LocalizationConfig
from clipclique.errors import ClipcliqueError
from clipclique.pose import DegeneratePoseError, correspondence_weights, fit_rigid
from clipclique.types import Hypothesis, Map, Observations

STAGES = ("descriptors", "similarity", "matching", "inliers", "pose", "verification")
NOT_CONFIDENT = "no pose with confidence >="  # how a frame refused by `min_confidence` says why


@dataclass
class MapIndex:
    """Map-side work done once per map and config."""

    map: Map
    built_for: tuple  # (descriptor, GraphConfig) this index was built with; localize checks it
    adjacency: sp.csr_matrix  # (N, N) semantic graph
    histograms: sp.csr_matrix | None  # (N, C^s) Semantic Histograms, when the descriptor uses them
    walks: sp.csr_matrix | None  # (N, C^s) X-View random-walk counts, when the descriptor uses them
    text_embeddings: np.ndarray | None = None  # (N, D) float64 copy of map.text_embeddings, made once, not per frame


@dataclass
class LocalizationResult:
    hypotheses: list[Hypothesis]  # best first, at most config.top_n
    candidates: np.ndarray  # (C, 2) int (observation index, landmark index) after initial matching
    candidate_scores: np.ndarray  # (C,) similarity of each candidate
    similarity: np.ndarray  # (K, N) the matrix the matching used
    num_cliques: int  # maximal cliques (or RANSAC/PROSAC hypotheses) considered
    cap_hit: str | None  # "max_cliques" | "time_limit" | None
    failure: str | None  # why there is no pose; None on success
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)  # seconds per stage (STAGES)


def index_map(map: Map, config: LocalizationConfig) -> MapIndex:
    """Semantic graph and the graph descriptors `config.similarity.descriptor` needs."""
    adjacency = graph.semantic_graph(map.ellipsoids.centers, config.graph.d_adj)
    histograms, walks = _graph_descriptors(adjacency, map.class_ids, len(map.class_names), config)
    text = None if map.text_embeddings is None else np.asarray(map.text_embeddings, np.float64)
    return MapIndex(map, _index_key(config), adjacency, histograms, walks, text)


def localize(observations: Observations, index: MapIndex, config: LocalizationConfig) -> LocalizationResult:
    """Ranked camera-to-map poses for one frame's observations."""
    _check_classes(observations, index.map)
    if index.built_for != _index_key(config):
        raise ClipcliqueError(
            f"the map index was built for {index.built_for}, not {_index_key(config)}: call index_map with this config"
        )
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = now - clock
        clock = now

    centers = observations.ellipsoids.centers
    query_graph = graph.semantic_graph(centers, config.graph.d_adj)
    histograms, walks = _graph_descriptors(query_graph, observations.class_ids, len(index.map.class_names), config)
    lap("descriptors")
    scores, notes = _similarity(observations, index, histograms, walks, config)
    lap("similarity")
    candidates, candidate_scores = matching.match(scores, config.matching)
    lap("matching")

    result = LocalizationResult([], candidates, candidate_scores, scores, 0, None, None, notes, timings)
    if len(observations) < 3:
        result.failure = f"fewer than 3 observations ({len(observations)})"
    elif len(np.unique(candidates[:, 0])) < 3:
        result.failure = f"fewer than 3 observations with a candidate landmark ({len(np.unique(candidates[:, 0]))})"
    elif config.inliers.method == "cliques":
        _solve_cliques(result, observations, index.map, config, lap)
    else:
        _solve_consensus(result, observations, index.map, config, lap)
    if result.failure is None and not result.hypotheses:
        result.failure = "no correspondence set determines a pose"
    _verify(result, observations, index.map, config)
    lap("verification")
    for stage in STAGES:
        timings.setdefault(stage, 0.0)
    return result


def _index_key(config: LocalizationConfig) -> tuple:
    return (config.similarity.descriptor, dataclasses.replace(config.graph))


def _graph_descriptors(
    adjacency: sp.csr_matrix, class_ids: np.ndarray, num_classes: int, config: LocalizationConfig
) -> tuple[sp.csr_matrix | None, sp.csr_matrix | None]:
    descriptor = config.similarity.descriptor
    histograms = walks = None
    if descriptor in ("fused", "sh"):
        histograms = graph.semantic_histograms(adjacency, class_ids, num_classes, config.graph.walk_length)
    if descriptor == "xview":
        rng = np.random.default_rng(config.graph.xview_seed)
        walks = graph.random_walk_descriptors(
            adjacency, class_ids, num_classes, config.graph.walk_length, config.graph.xview_walks, rng
        )
    return histograms, walks


def _similarity(
    observations: Observations,
    index: MapIndex,
    histograms: sp.csr_matrix | None,
    walks: sp.csr_matrix | None,
    config: LocalizationConfig,
) -> tuple[np.ndarray, list[str]]:
    descriptor = config.similarity.descriptor
    if descriptor == "xview":
        return similarity.walk_similarity(walks, index.walks), []
    if descriptor == "sh":
        return similarity.histogram_similarity(histograms, index.histograms), []
    missing = _missing_embeddings(observations, index.map)
    if descriptor == "clip":
        if missing:
            raise ClipcliqueError(f"descriptor 'clip' needs CLIP embeddings, but {missing}")
        return similarity.clip_similarity(observations.image_embeddings, index.text_embeddings), []
    sh = similarity.histogram_similarity(histograms, index.histograms)
    if missing:
        return sh, [f"no CLIP embeddings ({missing}): alpha = 0 (SH only)"]
    clip = similarity.clip_similarity(observations.image_embeddings, index.text_embeddings)
    return similarity.fuse(clip, sh, config.similarity.alpha), []


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


def _check_classes(observations: Observations, map: Map) -> None:
    ids = observations.class_ids
    if len(ids) and (ids.min() < 0 or ids.max() >= len(map.class_names)):
        raise ClipcliqueError(
            f"observation class ids must index the map's {len(map.class_names)} classes; got {ids.min()}..{ids.max()}"
        )


def _solve_cliques(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig, lap: Callable[[str], None]) -> None:
    """Maximal cliques of the compatibility graph ranked by summed similarity, one pose each."""
    settings = config.inliers
    edges = inliers.compatibility_graph(
        observations.ellipsoids.centers, map.ellipsoids.centers, result.candidates, settings.d_comp
    )
    cliques, result.cap_hit = inliers.maximal_cliques(
        edges, len(result.candidates), settings.min_clique_size, settings.max_cliques, settings.time_limit_s
    )
    result.num_cliques = len(cliques)
    ranked = inliers.rank_cliques(cliques, result.candidate_scores)
    lap("inliers")
    for clique in ranked:
        hypothesis = _hypothesis(result, observations, map, config, clique, float(result.candidate_scores[clique].sum()))
        if hypothesis is not None:
            result.hypotheses.append(hypothesis)
            if len(result.hypotheses) == config.top_n:
                break
    if not cliques:
        result.failure = f"no clique of {settings.min_clique_size} or more compatible correspondences"
    lap("pose")


def _solve_consensus(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig, lap: Callable[[str], None]) -> None:
    """RANSAC / PROSAC inlier sets, each refit with the weighted pose."""
    settings = config.inliers
    obs, lm = result.candidates[:, 0], result.candidates[:, 1]
    image = None
    if settings.verification == "overlap":
        verification.require_image(observations, "inliers.verification = overlap (set it to centers otherwise)")
        image = inliers.ImageEvidence(map.ellipsoids, observations.boxes, observations.camera, settings.iou_threshold)
    consensus = inliers.sample_consensus(
        observations.ellipsoids.centers,
        map.ellipsoids.centers,
        result.candidates,
        result.candidate_scores,
        iterations=settings.ransac_iterations,
        threshold=settings.inlier_threshold,
        rng=np.random.default_rng(settings.seed),
        progressive=settings.method == "prosac",
        same_class=observations.class_ids[obs] == map.class_ids[lm],
        keep=config.top_n,
        image=image,
    )
    result.num_cliques = consensus.num_hypotheses
    lap("inliers")
    for members, score in zip(consensus.inlier_sets, consensus.scores):
        hypothesis = _hypothesis(result, observations, map, config, members, score)
        if hypothesis is not None:
            result.hypotheses.append(hypothesis)
    if not consensus.inlier_sets:
        result.failure = "no minimal set of 3 distinct, non-collinear correspondences"
    lap("pose")


def _hypothesis(
    result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig, members: np.ndarray, score: float
) -> Hypothesis | None:
    """The weighted pose of a correspondence set, or None when the set is degenerate."""
    pairs = result.candidates[members]
    weights = correspondence_weights(
        result.candidate_scores[members],
        observations.ellipsoids.axes[pairs[:, 0]],
        map.ellipsoids.axes[pairs[:, 1]],
        config.pose.weights,
    )
    try:
        pose = fit_rigid(observations.ellipsoids.centers[pairs[:, 0]], map.ellipsoids.centers[pairs[:, 1]], weights)
    except DegeneratePoseError:
        return None
    return Hypothesis(pose, pairs, score)


def _verify(result: LocalizationResult, observations: Observations, map: Map, config: LocalizationConfig) -> None:
    """Verification score and confidence of every hypothesis, then `inliers.rerank` and `min_confidence`.

    Observations without boxes and camera (a library caller's own) are left unverified, unless
    re-ranking or a confidence floor asks for it.
    """
    wanted = config.inliers.rerank != "none" or config.min_confidence > 0
    if observations.boxes is None or observations.camera is None:
        if wanted:
            verification.require_image(observations, "inliers.rerank and min_confidence")
        return
    if not result.hypotheses:
        return
    checked = verification.verify(result.hypotheses, observations, map)
    model = confidence.load_model(config.confidence_model)
    probability = (None if model is None else
                   model.predict(confidence.Evidence(result.hypotheses, checked, result.similarity, len(observations))))
    for rank, hypothesis in enumerate(result.hypotheses):
        hypothesis.verification = float(checked.score[rank])
        hypothesis.confidence = None if probability is None else float(probability[rank])
    if config.inliers.rerank != "none":
        if config.inliers.rerank == "confidence" and probability is None:
            raise ClipcliqueError("inliers.rerank = confidence needs a confidence model (none is shipped in this build)")
        key = checked.score if config.inliers.rerank == "verification" else probability
        result.hypotheses = [result.hypotheses[i] for i in np.argsort(-key, kind="stable")]
    if config.min_confidence > 0:
        if probability is None:
            raise ClipcliqueError("min_confidence needs a confidence model (none is shipped in this build)")
        best = max(h.confidence for h in result.hypotheses)
        result.hypotheses = [h for h in result.hypotheses if h.confidence >= config.min_confidence]
        if not result.hypotheses:
            result.failure = f"{NOT_CONFIDENT} {config.min_confidence:g} (best {best:.2f})"
