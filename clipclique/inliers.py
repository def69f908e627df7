"""Outlier rejection: the compatibility graph and its maximal cliques, and RANSAC / PROSAC.

Compatibility graph: nodes are candidate correspondences `(observation, landmark)`. Two
candidates a, b are compatible when a rigid motion could explain both, i.e. the distance between
their observations equals the distance between their landmarks up to `d_comp`:
`| |o_a - o_b| - |m_a - m_b| | < d_comp`, and they share neither the observation nor the
landmark (one object cannot be two, so a clique is a one-to-one correspondence set).

The pipeline asks `cliquesearch.top_cliques` for the N heaviest maximal cliques (summed
similarity): a branch-and-bound search in compiled code that cuts whatever cannot reach the
N-th best, instead of enumerating every maximal clique and ranking them; same N cliques, same
order. `maximal_cliques` (igraph: Bron-Kerbosch with pivoting in C) enumerates them all; with
`rank_cliques` it is the reference the search is tested and benchmarked against.

Memory is bounded whatever the map: `affordable_candidates` keeps the best-scored candidates
whose landmark pairs within reach fit `max_pairs` (5,000 identical overlapping landmarks would
otherwise ask for gigabytes of pairs), and the pipeline reports the cap it used.

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
from numba import njit
from scipy.spatial import cKDTree

from clipclique.cliquesearch import clique_total
from clipclique.pose import fit_rigid_batch
from clipclique.types import Camera, Ellipsoids
from clipclique.verification import candidate_overlap

FIRST_ROUND = 1_000  # cliques asked for in the first enumeration round
MAX_PAIRS = 2_000_000  # landmark pairs the compatibility test may hold in memory (about 100 MB)
CHUNK = 256  # RANSAC hypotheses verified at once (bounds memory to CHUNK x C residuals)


def compatibility_graph(
    observed_centers: np.ndarray,
    landmark_centers: np.ndarray,
    candidates: np.ndarray,
    d_comp: float,
    slack: np.ndarray | None = None,
) -> np.ndarray:
    """(E, 2) edges `i < j` between compatible candidates (rows of `candidates`).

    `slack` (C,) widens the test per candidate: pair (a, b) passes within
    `d_comp + slack[a] + slack[b]` metres (None: `d_comp` for every pair).

    Two landmarks farther apart than the widest observation pair plus the widest tolerance
    cannot pass the test, so only landmark pairs within that reach (a KD-tree query) are tested:
    the cost grows with the candidates' neighbourhoods, not with the square of their number.
    """
    if len(candidates) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    slack = np.zeros(len(candidates)) if slack is None else np.asarray(slack, dtype=np.float64)
    obs, lm = candidates[:, 0], candidates[:, 1]
    observed = np.linalg.norm(observed_centers[:, None] - observed_centers[None], axis=-1)
    points = landmark_centers[lm]
    pairs = cKDTree(points).query_pairs(_reach(observed, d_comp, slack), output_type="ndarray").astype(np.int64)
    return _compatible(pairs, points, obs, lm, observed, d_comp, slack)


@njit(cache=True)
def _compatible(pairs, points, obs, lm, observed, d_comp, slack):
    """The pairs that pass the rigid distance test, in one compiled pass (vectorized numpy made
    six temporaries of the pair count: 10x slower at 300,000 pairs)."""
    keep = np.zeros(len(pairs), np.bool_)
    for p in range(len(pairs)):
        a, b = pairs[p, 0], pairs[p, 1]
        if obs[a] == obs[b] or lm[a] == lm[b]:
            continue
        mapped = math.sqrt((points[a, 0] - points[b, 0]) ** 2 + (points[a, 1] - points[b, 1]) ** 2
                           + (points[a, 2] - points[b, 2]) ** 2)
        keep[p] = abs(observed[obs[a], obs[b]] - mapped) < d_comp + slack[a] + slack[b]
    return pairs[keep]


def affordable_candidates(
    observed_centers: np.ndarray,
    landmark_centers: np.ndarray,
    candidates: np.ndarray,
    scores: np.ndarray,
    d_comp: float,
    slack: np.ndarray | None = None,
    max_pairs: int = MAX_PAIRS,
) -> np.ndarray:
    """Indices (sorted) of the candidates `compatibility_graph` may test without holding more
    than `max_pairs` pairs: all of them when they fit, else the longest best-scored run (ties by
    row) that fits, found by bisection on pair counts (a KD-tree's dual-tree count: no pairs
    are materialized, memory stays linear in the candidates)."""
    if len(candidates) * (len(candidates) - 1) // 2 <= max_pairs:
        return np.arange(len(candidates))
    observed = np.linalg.norm(observed_centers[:, None] - observed_centers[None], axis=-1)
    reach = _reach(observed, d_comp, slack)
    points = landmark_centers[candidates[:, 1]]
    if _pairs_within(points, reach) <= max_pairs:
        return np.arange(len(candidates))
    best = np.argsort(-scores, kind="stable")
    fits, too_many = 0, len(candidates)  # bisection bounds on the run's length
    while too_many - fits > 1:
        middle = (fits + too_many) // 2
        if _pairs_within(points[best[:middle]], reach) <= max_pairs:
            fits = middle
        else:
            too_many = middle
    return np.sort(best[:fits])


def _pairs_within(points: np.ndarray, reach: float) -> int:
    """Pairs of distinct points at most `reach` apart, counted without listing them."""
    tree = cKDTree(points)
    return (int(tree.count_neighbors(tree, reach)) - len(points)) // 2


def _reach(observed: np.ndarray, d_comp: float, slack: np.ndarray | None) -> float:
    """Farthest landmark pair that can pass the test: the widest observation pair plus the widest tolerance."""
    widest = 0.0 if slack is None or len(slack) == 0 else 2.0 * float(slack.max())
    return float(observed.max()) + d_comp + widest


def partial_view_slack(
    observed_axes: np.ndarray, landmark_axes: np.ndarray, fraction: float, cap: float, min_deficit: float
) -> np.ndarray:
    """(C,) extra compatibility tolerance per candidate for objects seen in part.

    Seeing a part of length l of an object whose semi-axis is L moves the observed centre by up
    to L - l/2 = L - (observed semi-axis) along that axis. The deficit is compared axis by axis
    after sorting both sets of semi-axes (their order is not comparable). Only a deficit of at
    least `min_deficit` metres earns slack (a smaller one the test already absorbs; widening it
    for the many small objects of a cluttered desk adds false edges): `fraction` of it, at most
    `cap` metres. A complete view gets none.
    """
    if fraction == 0 or len(observed_axes) == 0:
        return np.zeros(len(observed_axes))
    deficit = (np.sort(landmark_axes, axis=1) - np.sort(observed_axes, axis=1)).max(axis=1)
    return np.where(deficit >= min_deficit, np.minimum(fraction * deficit, cap), 0.0)


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
    """Cliques sorted by summed similarity (`clique_total`), best first; ties by the sorted member
    lists, lexicographically smaller first: the order `top_cliques` returns."""
    if not cliques:
        return []
    totals = clique_total(cliques, scores)
    members = [np.sort(c) for c in cliques]
    longest = max(len(c) for c in members)
    padded = np.full((len(members), longest), -1)  # a shorter list that is a prefix ranks first
    padded[np.arange(longest) < np.array([len(c) for c in members])[:, None]] = np.concatenate(members)
    order = np.lexsort((*padded.T[::-1], -totals))
    return [members[i] for i in order]


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
