"""Pose refinement: a clique's pose refitted with every observation it brings next to a matching landmark.

A clique holds three or four objects of a crowded desk, a few decimetres apart: their centres
fix the rotation poorly, and a camera a metre or two away then lands half a metre to two metres
off. Moved into the map with that pose, most other observations fall near their own landmarks;
taking every observation that lands within `radius` of a landmark it is similar to (one-to-one,
nearest first) and refitting with all of them pins the pose down. Done `rounds` times per hypothesis.
"""

from __future__ import annotations

import itertools

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from clipclique.config import PoseWeights
from clipclique.pose import correspondence_weights, fit_rigid_batch
from clipclique.types import Hypothesis, Map, Observations, Pose


def nearby_pairs(pose: Pose, observations: Observations, map: Map, similarity: np.ndarray, radius: float,
                 landmarks: cKDTree | None = None) -> np.ndarray:
    """(M, 2) (observation, landmark) pairs, one-to-one, nearest first (ties by observation, then
    landmark): each observation moved into the map by `pose` lies within `radius` of a landmark its
    similarity to is positive."""
    return nearby_pairs_of([pose], observations, map, similarity, radius, landmarks)[0]


def nearby_pairs_of(poses: list[Pose], observations: Observations, map: Map, similarity: np.ndarray,
                    radius: float, landmarks: cKDTree | None = None) -> list[np.ndarray]:
    """`nearby_pairs` of each pose, the observations moved by all of them at once. `landmarks` is a
    KD-tree of the map's centres (None: built here), so a map of 47,000 landmarks costs a ball query
    per observation, not a (K, N) distance matrix."""
    rotations = np.array([pose.rotation for pose in poses]).reshape(-1, 3, 3)
    translations = np.array([pose.translation for pose in poses]).reshape(-1, 3)
    moved_by_pose = np.einsum("bij,kj->bki", rotations, observations.ellipsoids.centers) + translations[:, None]
    tree = cKDTree(map.ellipsoids.centers) if landmarks is None else landmarks
    out = []
    for moved in moved_by_pose:
        near = tree.query_ball_point(moved, radius * (1 + 1e-9) + 1e-12)  # a hair wider than the strict test below
        counts = np.fromiter((len(row) for row in near), np.int64, len(near))
        obs = np.repeat(np.arange(len(moved)), counts)
        lm = np.fromiter(itertools.chain.from_iterable(near), np.int64, int(counts.sum()))
        distance = np.linalg.norm(moved[obs] - map.ellipsoids.centers[lm], axis=-1)  # the dense matrix's very values
        allowed = (distance < radius) & (similarity[obs, lm] > 0)
        obs, lm, distance = obs[allowed], lm[allowed], distance[allowed]
        order = np.lexsort((lm, obs, distance))
        out.append(_one_to_one(obs[order], lm[order], len(moved), len(map)))
    return out


@njit(cache=True)
def _one_to_one(observations: np.ndarray, landmarks: np.ndarray, num_observations: int,
                num_landmarks: int) -> np.ndarray:
    """(M, 2) the pairs (observations[i], landmarks[i]) taken greedily in the order given, each one's
    observation and landmark not taken yet (a query's few dozen pairs per pose: a Python loop cost more
    than the rest of the refinement)."""
    used_observation, used_landmark = np.zeros(num_observations, np.bool_), np.zeros(num_landmarks, np.bool_)
    pairs = np.empty((len(observations), 2), np.int64)
    taken = 0
    for k, n in zip(observations, landmarks):
        if not used_observation[k] and not used_landmark[n]:
            used_observation[k], used_landmark[n] = True, True
            pairs[taken, 0], pairs[taken, 1] = k, n
            taken += 1
    return pairs[:taken]


def refine(hypotheses: list[Hypothesis], observations: Observations, map: Map, similarity: np.ndarray, radius: float,
           weights: PoseWeights, rounds: int = 2, landmarks: cKDTree | None = None) -> None:
    """Each hypothesis's pose and correspondences replaced by the refit on its nearby pairs, in place,
    as long as they are at least as many as it had (a refit never rests on fewer objects). The
    hypotheses still refining are refitted together, one batch per round (a re-ranked frame has fifty).
    `landmarks`: a KD-tree of the map's centres (`nearby_pairs_of`; None: built once here)."""
    if hypotheses and landmarks is None:
        landmarks = cKDTree(map.ellipsoids.centers)
    active = list(hypotheses)
    for _ in range(rounds):
        if not active:
            return
        nearby = nearby_pairs_of([h.pose for h in active], observations, map, similarity, radius, landmarks)
        refits = [(hypothesis, pairs) for hypothesis, pairs in zip(active, nearby)
                  if len(pairs) >= max(3, len(hypothesis.correspondences))]
        if not refits:
            return
        sizes = np.array([len(pairs) for _, pairs in refits])
        valid = np.arange(sizes.max()) < sizes[:, None]
        padded = np.zeros((*valid.shape, 2), np.int64)
        padded[valid] = np.concatenate([pairs for _, pairs in refits])
        obs, lm = padded[..., 0], padded[..., 1]
        w = valid * correspondence_weights(similarity[obs, lm].ravel(), observations.ellipsoids.axes[obs].reshape(-1, 3),
                                           map.ellipsoids.axes[lm].reshape(-1, 3), weights).reshape(valid.shape)
        rotation, translation, ok = fit_rigid_batch(observations.ellipsoids.centers[obs], map.ellipsoids.centers[lm], w)
        ok &= np.count_nonzero(w, axis=1) >= 3
        active = []
        for b in np.flatnonzero(ok):
            hypothesis, pairs = refits[b]
            hypothesis.pose = Pose(rotation[b], translation[b])
            hypothesis.correspondences = pairs
            active.append(hypothesis)
