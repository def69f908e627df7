"""RANSAC / PROSAC sample consensus (the baselines' inlier stage).

Minimal sets of 3 candidates are drawn and each pose verified. As the paper (CLIP-Loc's
verification), by projected overlap (`image` given): every candidate landmark is projected into
the query image under the pose and its box compared with the observation's detection box; each
observation adds the IoU of its best candidate (same class, when classes are given), and
candidates with IoU >= `image.iou_threshold` are inliers. Without `image`, an MSAC-style centre
score (`inliers.verification = centers`): every observation whose candidate landmark lies within
`threshold` of the transformed observation centre adds `1 - residual / threshold`, counted once
per observation (its best candidate). When the candidates have no more 3-subsets than the
iteration budget, all of them are tried instead of drawing (exhaustive, and still deterministic).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from clipclique.pose.fit import fit_rigid_batch
from clipclique.types import Camera, Ellipsoids
from clipclique.verify.verification import candidate_overlap

CHUNK = 256  # hypotheses verified at once (bounds memory to CHUNK x C residuals; results do not depend on it)


@dataclass(kw_only=True)
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
        return Consensus(inlier_sets=[], scores=[], num_hypotheses=0)
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
    return Consensus(inlier_sets=inlier_sets, scores=set_scores, num_hypotheses=int(len(rotation)))


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
