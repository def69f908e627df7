"""Outlier rejection: the compatibility graph and its maximal cliques, and RANSAC / PROSAC.

Compatibility graph: nodes are candidate correspondences `(observation, landmark)`. Two
candidates a, b are compatible when a rigid motion could explain both, i.e. the distance between
their observations equals the distance between their landmarks up to `d_comp`:
`| |o_a - o_b| - |m_a - m_b| | < d_comp`, and they share neither the observation nor the
landmark (one object cannot be two, so a clique is a one-to-one correspondence set).

Maximal cliques are enumerated with igraph (Bron-Kerbosch with pivoting in C), which measured
2-7x faster than networkx's `find_cliques` on the compatibility graphs of 50 to 5,000 landmark
maps (tools/bench_core.py). Cliques of
fewer than `min_clique_size` (>= 3) are never returned: fewer than 3 points cannot fix a 6-DoF
pose. igraph's enumeration is not lazy, so it runs in rounds of growing `max_results`
(1,000, then doubling) up to `max_cliques`; the time limit is checked between rounds, and the
result reports which cap, if any, cut the enumeration short.

RANSAC / PROSAC (baselines) draw minimal sets of 3 candidates and verify each pose. As the paper
(CLIP-Loc's verification), by projected overlap (`image` given): every candidate landmark is
projected into the query image under the pose and its box compared with the observation's
detection box; each observation adds the IoU of its best candidate (same class, when classes are
given), and candidates with IoU >= `image.iou_threshold` are inliers. Without `image`, an
MSAC-style centre score (`inliers.verification = centers`): every observation whose candidate
landmark lies within `threshold` of the transformed observation centre adds
`1 - residual / threshold`, counted once per observation (its best candidate). When the candidates
have no more 3-subsets than the iteration budget, all of them are tried instead of drawing
(exhaustive, and still deterministic).
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass

import igraph
import numpy as np
from scipy.spatial import cKDTree

from clipclique.pose import fit_rigid_batch
from clipclique.types import Camera, Ellipsoids
from clipclique.verification import candidate_overlap

FIRST_ROUND = 1_000  # cliques asked for in the first enumeration round
CHUNK = 256  # RANSAC hypotheses verified at once (bounds memory to CHUNK x C residuals)


def compatibility_graph(
    observed_centers: np.ndarray, landmark_centers: np.ndarray, candidates: np.ndarray, d_comp: float
) -> np.ndarray:
    """(E, 2) edges `i < j` between compatible candidates (rows of `candidates`).

    Two landmarks farther apart than the widest observation pair plus `d_comp` cannot pass the
    test, so only landmark pairs within that reach (a KD-tree query) are tested: the cost grows
    with the candidates' neighbourhoods, not with the square of their number.
    """
    if len(candidates) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    obs, lm = candidates[:, 0], candidates[:, 1]
    observed = np.linalg.norm(observed_centers[:, None] - observed_centers[None], axis=-1)
    points = landmark_centers[lm]
    pairs = cKDTree(points).query_pairs(observed.max() + d_comp, output_type="ndarray").astype(np.int64)
    a, b = pairs[:, 0], pairs[:, 1]
    mapped = np.linalg.norm(points[a] - points[b], axis=1)
    keep = (np.abs(observed[obs[a], obs[b]] - mapped) < d_comp) & (obs[a] != obs[b]) & (lm[a] != lm[b])
    return pairs[keep]


def maximal_cliques(
    edges: np.ndarray, num_nodes: int, min_size: int = 3, max_cliques: int = 100_000, time_limit_s: float = 1.0
) -> tuple[list[np.ndarray], str | None]:
    """Maximal cliques of at least `min_size` nodes of the graph `edges` (E, 2) on `num_nodes` nodes,
    and the cap that stopped enumeration early.

    Returns (cliques as sorted index arrays, cap) where cap is "max_cliques", "time_limit" or None.
    """
    graph = igraph.Graph(n=num_nodes, edges=edges)
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


@dataclass
class ImageEvidence:
    """What verifying a pose by projected overlap needs."""

    landmarks: Ellipsoids  # the map's landmarks
    boxes: np.ndarray  # (K, 4) xyxy detection box of each observation
    camera: Camera
    iou_threshold: float  # a candidate whose boxes overlap this much is an inlier


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
    image: ImageEvidence | None = None,
) -> Consensus:
    """RANSAC (uniform minimal sets) or PROSAC (`progressive`: drawn from the best-scored
    candidates first, the pool growing to all of them), keeping the `keep` best distinct inlier sets.

    `same_class` (C,) bool marks candidates whose observation and landmark share a class; only
    those can be inliers. `image` switches verification from centre distances to projected overlap.
    """
    count = len(candidates)
    if count < 3 or iterations < 1:
        return Consensus([], [], 0)
    samples = _minimal_sets(scores, iterations, rng, progressive)
    obs, lm = candidates[:, 0], candidates[:, 1]
    samples = samples[_all_different(obs[samples]) & _all_different(lm[samples])]
    rotation, translation, ok = fit_rigid_batch(observed_centers[obs[samples]], landmark_centers[lm[samples]])
    rotation, translation = rotation[ok], translation[ok]

    by_obs = np.argsort(obs, kind="stable")
    group_starts = np.flatnonzero(np.r_[True, np.diff(obs[by_obs]) != 0])
    allowed = np.ones(count, dtype=bool) if same_class is None else same_class
    if image is None:
        source, target = observed_centers[obs], landmark_centers[lm]
        support_of = lambda r, t: _center_support(r, t, source, target, threshold)  # noqa: E731
    else:
        landmarks, boxes = image.landmarks.subset(lm), image.boxes[obs]
        support_of = lambda r, t: _overlap_support(r, t, landmarks, boxes, image)  # noqa: E731
    verification = np.empty(len(rotation))
    inlier_masks = np.empty((len(rotation), count), dtype=bool)
    for lo in range(0, len(rotation), CHUNK):
        support, inlier = support_of(rotation[lo : lo + CHUNK], translation[lo : lo + CHUNK])
        support = np.where(allowed, support, 0.0)
        inlier_masks[lo : lo + CHUNK] = allowed & inlier
        verification[lo : lo + CHUNK] = np.maximum.reduceat(support[:, by_obs], group_starts, axis=1).sum(axis=1)

    # Visit the best hypothesis of each distinct inlier set, best first.
    order = np.argsort(-verification, kind="stable")
    _, first = np.unique(np.packbits(inlier_masks[order], axis=1), axis=0, return_index=True)
    inlier_sets: list[np.ndarray] = []
    set_scores: list[float] = []
    for best in order[np.sort(first)]:
        if verification[best] <= 0 or len(inlier_sets) == keep:
            break
        if np.count_nonzero(inlier_masks[best]) < 3:
            continue
        support = support_of(rotation[best : best + 1], translation[best : best + 1])[0][0]
        inliers = _best_per_observation(np.flatnonzero(inlier_masks[best]), obs, -support)
        if len(inliers) >= 3 and not any(np.array_equal(inliers, known) for known in inlier_sets):
            inlier_sets.append(inliers)
            set_scores.append(float(verification[best]))
    return Consensus(inlier_sets, set_scores, int(len(rotation)))


def _center_support(rotation: np.ndarray, translation: np.ndarray, source: np.ndarray, target: np.ndarray,
                    threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(B, C) MSAC support `1 - residual / threshold` of each candidate per pose, and the inlier mask."""
    moved = np.einsum("bij,cj->bci", rotation, source) + translation[:, None, :]
    residual = np.linalg.norm(moved - target[None], axis=-1)
    inlier = residual < threshold
    return np.where(inlier, 1.0 - residual / threshold, 0.0), inlier


def _overlap_support(rotation: np.ndarray, translation: np.ndarray, landmarks: Ellipsoids, boxes: np.ndarray,
                     image: ImageEvidence) -> tuple[np.ndarray, np.ndarray]:
    """(B, C) IoU of each candidate's detection box with its projected landmark per pose, and the inlier mask."""
    iou = candidate_overlap(rotation, translation, landmarks, boxes, image.camera)
    return iou, iou >= image.iou_threshold


def _best_per_observation(inliers: np.ndarray, obs: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Of the inlier candidates, the one with the smallest residual (negated support) per observation (sorted)."""
    ranked = inliers[np.lexsort((residual[inliers], obs[inliers]))]
    first = np.r_[True, np.diff(obs[ranked]) != 0]
    return np.sort(ranked[first])


def _all_different(triples: np.ndarray) -> np.ndarray:
    return (triples[:, 0] != triples[:, 1]) & (triples[:, 0] != triples[:, 2]) & (triples[:, 1] != triples[:, 2])


def _minimal_sets(scores: np.ndarray, iterations: int, rng: np.random.Generator, progressive: bool) -> np.ndarray:
    """(I, 3) candidate indices: every 3-subset when there are no more than `iterations` of them
    (exhaustive beats random), else PROSAC's or RANSAC's draws."""
    count = len(scores)
    if math.comb(count, 3) <= iterations:
        return np.array(list(itertools.combinations(range(count), 3)), dtype=np.int64)
    if not progressive:
        return _uniform_samples(count, iterations, rng)
    return np.argsort(-scores, kind="stable")[_prosac_samples(count, iterations, rng)]


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
