"""A literal, independent reading of CLIP-Clique (Matsuzaki et al., RA-L 2024), for comparison.

Shares nothing with `clipclique/` but the data types: every stage is re-written here as plainly as
the paper states it, with networkx for the maximal cliques, so the benchmark can stand the project
beside a reading that has none of its design decisions. Paper defaults: d_adj = 0.8 m, walks of
s = 3 nodes (stepping back allowed), alpha = 0.7, adaptive matching over the top M = N / 4,
d_comp = 0.3 m, cliques of 3 or more ranked by summed similarity, pose by weighted least squares
with w = s_total * w_com. No similarity threshold, no caps: what the paper describes, nothing more.
"""

from __future__ import annotations

import math
from collections import Counter

import networkx as nx
import numpy as np

from clipclique.types import Hypothesis, Map, Observations, Pose


def neighbours(centers: np.ndarray, d_adj: float) -> list[list[int]]:
    """Objects whose centres are closer than d_adj (the semantic graph), as adjacency lists."""
    distance = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    return [[j for j in range(len(centers)) if j != i and distance[i, j] < d_adj] for i in range(len(centers))]


def semantic_histograms(centers: np.ndarray, classes: np.ndarray, d_adj: float, length: int = 3) -> list[Counter]:
    """Per node: counts of the class sequences of every walk of `length` nodes that starts at it."""
    adjacency = neighbours(centers, d_adj)
    histograms = []
    for start in range(len(centers)):
        walks = [(start,)]
        for _ in range(length - 1):
            walks = [walk + (step,) for walk in walks for step in adjacency[walk[-1]]]
        histograms.append(Counter(tuple(int(classes[node]) for node in walk) for walk in walks))
    return histograms


def histogram_similarity(query: list[Counter], landmarks: list[Counter]) -> np.ndarray:
    """Cosine similarity of the histograms (0 where either is empty)."""
    def norm(h: Counter) -> float:
        return math.sqrt(sum(v * v for v in h.values()))

    out = np.zeros((len(query), len(landmarks)))
    for i, q in enumerate(query):
        for j, m in enumerate(landmarks):
            if norm(q) and norm(m):
                out[i, j] = sum(v * m[key] for key, v in q.items()) / (norm(q) * norm(m))
    return out


def adaptive_matching(similarity: np.ndarray, fraction: float = 0.25) -> list[tuple[int, int, float]]:
    """Per observation: of its M most similar landmarks, those before the largest similarity drop."""
    m = max(2, math.ceil(fraction * similarity.shape[1]))
    pairs = []
    for i, row in enumerate(similarity):
        order = sorted(range(len(row)), key=lambda j: -row[j])[:m]
        values = [row[j] for j in order]
        gaps = [values[k] - values[k + 1] for k in range(len(values) - 1)]
        keep = gaps.index(max(gaps)) + 1 if gaps else len(order)
        pairs += [(i, j, float(row[j])) for j in order[:keep]]
    return pairs


def compatibility_graph(pairs, observed: np.ndarray, mapped: np.ndarray, d_comp: float) -> nx.Graph:
    """Nodes are candidate pairs; an edge joins two whose observation and landmark distances agree."""
    graph = nx.Graph()
    graph.add_nodes_from(range(len(pairs)))
    for a in range(len(pairs)):
        for b in range(a + 1, len(pairs)):
            (obs_a, lm_a, _), (obs_b, lm_b, _) = pairs[a], pairs[b]
            if obs_a != obs_b and lm_a != lm_b:
                gap = abs(np.linalg.norm(observed[obs_a] - observed[obs_b])
                          - np.linalg.norm(mapped[lm_a] - mapped[lm_b]))
                if gap < d_comp:
                    graph.add_edge(a, b)
    return graph


def weighted_pose(source: np.ndarray, target: np.ndarray, weights: np.ndarray) -> Pose | None:
    """argmin sum w |R p + t - q|^2 by SVD (Umeyama without scale); None for collinear points."""
    w = weights / weights.sum()
    ps, qs = w @ source, w @ target
    a, b = source - ps, target - qs
    if np.linalg.svd(a, compute_uv=False)[1] < 1e-6:
        return None
    u, _, vt = np.linalg.svd((b * w[:, None]).T @ a)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ d @ vt
    return Pose(rotation, qs - rotation @ ps)


def localize(observations: Observations, map: Map, alpha: float = 0.7, d_adj: float = 0.8, d_comp: float = 0.3,
             top_n: int = 5) -> list[Hypothesis]:
    """The paper's pipeline, stage by stage; alpha = 0 (or no embeddings) is SH only."""
    observed, mapped = observations.ellipsoids.centers, map.ellipsoids.centers
    if len(observed) < 3:
        return []
    similarity = histogram_similarity(semantic_histograms(observed, observations.class_ids, d_adj),
                                      semantic_histograms(mapped, map.class_ids, d_adj))
    if alpha > 0 and observations.image_embeddings is not None and map.text_embeddings is not None:
        clip = np.asarray(observations.image_embeddings, float) @ np.asarray(map.text_embeddings, float).T
        similarity = alpha * clip + (1 - alpha) * similarity
    pairs = adaptive_matching(similarity)
    graph = compatibility_graph(pairs, observed, mapped, d_comp)
    cliques = [c for c in nx.find_cliques(graph) if len(c) >= 3]
    cliques.sort(key=lambda c: -sum(pairs[n][2] for n in c))
    hypotheses = []
    for clique in cliques:
        obs = np.array([pairs[n][0] for n in clique])
        lm = np.array([pairs[n][1] for n in clique])
        score = np.array([max(pairs[n][2], 0.0) for n in clique])
        o_axes, m_axes = observations.ellipsoids.axes[obs], map.ellipsoids.axes[lm]
        completeness = np.minimum(1.0, np.sqrt((o_axes**2).sum(1) / (m_axes**2).sum(1)))
        weights = score * completeness
        pose = weighted_pose(observed[obs], mapped[lm], weights) if weights.sum() > 0 else None
        if pose is not None:
            hypotheses.append(Hypothesis(pose, np.column_stack((obs, lm)), float(score.sum())))
        if len(hypotheses) == top_n:
            break
    return hypotheses
