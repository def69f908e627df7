"""The descriptor and similarity stages of one query: its graph descriptors, its similarity to the map's
landmarks (the descriptor `similarity.descriptor` names, CLIP fused with SH where both are there) and what
look-alike matching needs of it.

It exists so that `clipclique.pipeline` stays the composition of the stages: the map side is its `MapIndex`,
read here through `MapSide` (the fields these stages use), so that this room never imports the pipeline.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import scipy.sparse as sp

from clipclique.config import LocalizationConfig
from clipclique.descriptors import graph, matching, similarity
from clipclique.errors import ClipcliqueError
from clipclique.types import Map, Observations


class MapSide(Protocol):
    """What the query's descriptors and similarity read of the map's index (clipclique.pipeline.MapIndex)."""

    map: Map
    histograms_by_bin: sp.csr_matrix | None
    walks: sp.csr_matrix | None
    text_embeddings: np.ndarray | None
    class_kernel: sp.csr_matrix | None
    class_distributions: sp.csr_matrix | None
    kernel_by_landmark: np.ndarray | None
    class_groups: matching.ClassGroups | None


def graph_descriptors(
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


def descriptors(
    observations: Observations, index: MapSide, config: LocalizationConfig
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
    return graph_descriptors(query_graph, observations.class_ids, num_classes, config)


def scores(
    observations: Observations,
    index: MapSide,
    histograms: graph.SparseRows | None,
    walks: sp.csr_matrix | None,
    config: LocalizationConfig,
) -> tuple[np.ndarray, list[str]]:
    """(observations x landmarks) similarity by `similarity.descriptor`, and the notes it leaves (SH alone where
    the CLIP embeddings are missing)."""
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
    observations: Observations, index: MapSide, histograms: graph.SparseRows, config: LocalizationConfig
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


def lookalikes(observations: Observations, index: MapSide, config: LocalizationConfig) -> matching.Lookalikes | None:
    """What `matching.lookalike_candidates` needs of this query; None when that is off."""
    settings = config.matching
    if (settings.strategy != "adaptive" or settings.lookalike_candidates == 0 or config.similarity.lookalike_weight == 0
            or index.class_groups is None):
        return None
    return matching.Lookalikes(groups=index.class_groups, classes=observations.class_ids,
                               axes=np.asarray(observations.ellipsoids.axes, np.float64))


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
