"""Outlier rejection: the compatibility graph and its maximal cliques, and RANSAC / PROSAC.

Compatibility graph: nodes are candidate correspondences `(observation, landmark)`. Two
candidates a, b are compatible when a rigid motion could explain both, i.e. the distance between
their observations equals the distance between their landmarks up to `d_comp`:
`| |o_a - o_b| - |m_a - m_b| | < d_comp`, and they share neither the observation nor the
landmark (one object cannot be two, so a clique is a one-to-one correspondence set).

Maximal cliques are enumerated with igraph (Bron-Kerbosch with pivoting in C), which measured
4-10x faster than networkx's `find_cliques` on these graphs (tools/bench_core.py). Cliques of
fewer than `min_clique_size` (>= 3) are never returned: fewer than 3 points cannot fix a 6-DoF
pose. igraph's enumeration is not lazy, so it runs in rounds of growing `max_results`
(1,000, then doubling) up to `max_cliques`; the time limit is checked between rounds, and the
result reports which cap, if any, cut the enumeration short.

RANSAC / PROSAC (baselines) draw minimal sets of 3 candidates and verify each pose by an
MSAC-style score, a cheaper stand-in for the paper's projected overlap: every observation whose
candidate landmark (of the same class, when classes are given) lies within `threshold` of the
transformed observation centre adds `1 - residual / threshold`, counted once per observation
(its best candidate).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import igraph
import numpy as np

from clipclique.pose import fit_rigid_batch

FIRST_ROUND = 1_000  # cliques asked for in the first enumeration round
CHUNK = 256  # RANSAC hypotheses verified at once (bounds memory to CHUNK x C residuals)


def compatibility_graph(
    observed_centers: np.ndarray, landmark_centers: np.ndarray, candidates: np.ndarray, d_comp: float
) -> np.ndarray:
    """(C, C) boolean adjacency of the candidates' pairwise rigid-distance compatibility."""
    obs, lm = candidates[:, 0], candidates[:, 1]
    observed = _pairwise_distances(observed_centers[obs])
    mapped = _pairwise_distances(landmark_centers[lm])
    return (np.abs(observed - mapped) < d_comp) & (obs[:, None] != obs[None, :]) & (lm[:, None] != lm[None, :])


def maximal_cliques(
    adjacency: np.ndarray, min_size: int = 3, max_cliques: int = 100_000, time_limit_s: float = 1.0
) -> tuple[list[np.ndarray], str | None]:
    """Maximal cliques of at least `min_size` nodes, and the cap that stopped enumeration early.

    Returns (cliques as sorted index arrays, cap) where cap is "max_cliques", "time_limit" or None.
    """
    edges = np.argwhere(np.triu(adjacency, 1))
    graph = igraph.Graph(n=len(adjacency), edges=edges)
    start = time.perf_counter()
    wanted = min(FIRST_ROUND, max_cliques)
    while True:
        found = graph.maximal_cliques(min=min_size, max_results=wanted + 1)
        if len(found) <= wanted:
            return [np.array(sorted(c)) for c in found], None
        if wanted == max_cliques:
            return [np.array(sorted(c)) for c in found[:wanted]], "max_cliques"
        if time.perf_counter() - start > time_limit_s:
            return [np.array(sorted(c)) for c in found[:wanted]], "time_limit"
        wanted = min(2 * wanted, max_cliques)


def rank_cliques(cliques: list[np.ndarray], scores: np.ndarray) -> list[np.ndarray]:
    """Cliques sorted by summed similarity of their candidates, best first (stable)."""
    totals = np.array([scores[c].sum() for c in cliques])
    return [cliques[i] for i in np.argsort(-totals, kind="stable")]


@dataclass
class Consensus:
    """What RANSAC / PROSAC found: distinct inlier sets, best first."""

    inlier_sets: list[np.ndarray]  # candidate indices, one per observation
    scores: list[float]  # verification score of each set
    num_hypotheses: int  # minimal sets drawn and verified


def sample_consensus(
    observed_centers: np.ndarray,
    landmark_centers: np.ndarray,
    candidates: np.ndarray,
    scores: np.ndarray,
    *,
    iterations: int,
    threshold: float,
    rng: np.random.Generator,
    progressive: bool = False,
    same_class: np.ndarray | None = None,
    keep: int = 5,
) -> Consensus:
    """RANSAC (uniform minimal sets) or PROSAC (`progressive`: drawn from the best-scored
    candidates first, the pool growing to all of them), keeping the `keep` best distinct inlier sets.

    `same_class` (C,) bool marks candidates whose observation and landmark share a class; only
    those can be inliers.
    """
    count = len(candidates)
    if count < 3 or iterations < 1:
        return Consensus([], [], 0)
    order = np.argsort(-scores, kind="stable") if progressive else np.arange(count)
    samples = order[_prosac_samples(count, iterations, rng) if progressive else _uniform_samples(count, iterations, rng)]
    obs, lm = candidates[:, 0], candidates[:, 1]
    distinct = _all_different(obs[samples]) & _all_different(lm[samples])
    samples = samples[distinct]
    rotation, translation, ok = fit_rigid_batch(observed_centers[obs[samples]], landmark_centers[lm[samples]])
    rotation, translation = rotation[ok], translation[ok]

    by_obs = np.argsort(obs, kind="stable")
    group_starts = np.flatnonzero(np.r_[True, np.diff(obs[by_obs]) != 0])
    allowed = np.ones(count, dtype=bool) if same_class is None else same_class
    source, target = observed_centers[obs], landmark_centers[lm]
    verification = np.empty(len(rotation))
    for lo in range(0, len(rotation), CHUNK):
        residual = _residuals(rotation[lo : lo + CHUNK], translation[lo : lo + CHUNK], source, target)
        support = np.where(allowed & (residual < threshold), 1.0 - residual / threshold, 0.0)
        verification[lo : lo + CHUNK] = np.maximum.reduceat(support[:, by_obs], group_starts, axis=1).sum(axis=1)

    inlier_sets: list[np.ndarray] = []
    set_scores: list[float] = []
    seen: set[bytes] = set()
    for best in np.argsort(-verification, kind="stable"):
        if verification[best] <= 0 or len(inlier_sets) == keep:
            break
        residual = _residuals(rotation[best : best + 1], translation[best : best + 1], source, target)[0]
        inliers = _best_per_observation(np.flatnonzero(allowed & (residual < threshold)), obs, residual)
        key = inliers.tobytes()
        if len(inliers) >= 3 and key not in seen:
            seen.add(key)
            inlier_sets.append(inliers)
            set_scores.append(float(verification[best]))
    return Consensus(inlier_sets, set_scores, int(len(rotation)))


def _pairwise_distances(points: np.ndarray) -> np.ndarray:
    return np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)


def _residuals(rotation: np.ndarray, translation: np.ndarray, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(B, C) distance between each transformed source point and its target, per pose."""
    moved = np.einsum("bij,cj->bci", rotation, source) + translation[:, None, :]
    return np.linalg.norm(moved - target[None], axis=-1)


def _best_per_observation(inliers: np.ndarray, obs: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Of the inlier candidates, the one with the smallest residual per observation (sorted)."""
    ranked = inliers[np.lexsort((residual[inliers], obs[inliers]))]
    first = np.r_[True, np.diff(obs[ranked]) != 0]
    return np.sort(ranked[first])


def _all_different(triples: np.ndarray) -> np.ndarray:
    return (triples[:, 0] != triples[:, 1]) & (triples[:, 0] != triples[:, 2]) & (triples[:, 1] != triples[:, 2])


def _uniform_samples(count: int, iterations: int, rng: np.random.Generator) -> np.ndarray:
    """(I, 3) positions, three distinct ones per row, uniform over [0, count)."""
    return _three_distinct(np.full(iterations, count), rng)


def _prosac_samples(count: int, iterations: int, rng: np.random.Generator) -> np.ndarray:
    """(I, 3) positions into the score-sorted candidates, following PROSAC's growth schedule
    (Chum & Matas 2005): draw t uses the best n(t) candidates and always includes the n(t)-th;
    once the schedule reaches all candidates, draws are uniform (plain RANSAC)."""
    m = 3
    n = np.arange(m, count + 1)
    # T_n: expected draws among the top n, T_n = T_count * prod_i (n - i) / (count - i), T_count = iterations.
    t_n = iterations * np.exp(np.log((n[:, None] - np.arange(m)) / (count - np.arange(m))).sum(axis=1))
    t_prime = 1.0 + np.r_[0.0, np.cumsum(np.ceil(np.diff(t_n)))]
    pool = m + np.searchsorted(t_prime, np.arange(1, iterations + 1), side="left")
    samples = _three_distinct(np.full(iterations, count), rng)
    grown = pool <= count
    newest = pool[grown] - 1
    samples[grown] = np.column_stack((_two_distinct(newest, rng), newest))
    return samples


def _two_distinct(size: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    a = (rng.random(len(size)) * size).astype(np.int64)
    b = (rng.random(len(size)) * (size - 1)).astype(np.int64)
    b += b >= a
    return np.column_stack((a, b))


def _three_distinct(size: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    ab = _two_distinct(size, rng)
    low, high = ab.min(axis=1), ab.max(axis=1)
    c = (rng.random(len(size)) * (size - 2)).astype(np.int64)
    c += c >= low
    c += c >= high
    return np.column_stack((ab, c))
