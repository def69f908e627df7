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
from scipy.spatial import cKDTree

from clipclique.config import PoseWeights
from clipclique.pose import correspondence_weights, fit_rigid_batch
from clipclique.types import Hypothesis, Map, Observations, Pose


def nearby_pairs(pose: Pose, observations: Observations, map: Map, similarity: np.ndarray, radius: float,
                 landmarks: cKDTree | None = None) -> np.ndarray:
    """(M, 2) (observation, landmark) pairs, one-to-one, nearest first (ties by observation, then
    landmark): each observation moved into the map by `pose` lies within `radius` of a landmark its
    similarity to is positive. `landmarks` is a KD-tree of the map's centres (None: built here), so a
    map of 47,000 landmarks costs a ball query per observation, not a (K, N) distance matrix."""
    moved = pose.apply(observations.ellipsoids.centers)
    tree = cKDTree(map.ellipsoids.centers) if landmarks is None else landmarks
    near = tree.query_ball_point(moved, radius * (1 + 1e-9) + 1e-12)  # a hair wider than the strict test below
    counts = np.fromiter((len(row) for row in near), np.int64, len(near))
    obs = np.repeat(np.arange(len(moved)), counts)
    lm = np.fromiter(itertools.chain.from_iterable(near), np.int64, int(counts.sum()))
    distance = np.linalg.norm(moved[obs] - map.ellipsoids.centers[lm], axis=-1)  # the dense matrix's very values
    allowed = (distance < radius) & (similarity[obs, lm] > 0)
    obs, lm, distance = obs[allowed], lm[allowed], distance[allowed]
    used_obs, used_lm, pairs = set(), set(), []
    for i in np.lexsort((lm, obs, distance)):
        k, n = obs[i], lm[i]
        if k not in used_obs and n not in used_lm:
            used_obs.add(k)
            used_lm.add(n)
            pairs.append((k, n))
    return np.array(pairs, np.int64).reshape(-1, 2)


def refine(hypotheses: list[Hypothesis], observations: Observations, map: Map, similarity: np.ndarray, radius: float,
           weights: PoseWeights, rounds: int = 2, landmarks: cKDTree | None = None) -> None:
    """Each hypothesis's pose and correspondences replaced by the refit on its nearby pairs, in place,
    as long as they are at least as many as it had (a refit never rests on fewer objects).
    `landmarks`: a KD-tree of the map's centres (`nearby_pairs`; None: built once here)."""
    if hypotheses and landmarks is None:
        landmarks = cKDTree(map.ellipsoids.centers)
    for hypothesis in hypotheses:
        for _ in range(rounds):
            pairs = nearby_pairs(hypothesis.pose, observations, map, similarity, radius, landmarks)
            if len(pairs) < max(3, len(hypothesis.correspondences)):
                break
            obs, lm = pairs[:, 0], pairs[:, 1]
            w = correspondence_weights(similarity[obs, lm], observations.ellipsoids.axes[obs], map.ellipsoids.axes[lm],
                                       weights)
            rotation, translation, ok = fit_rigid_batch(observations.ellipsoids.centers[obs][None],
                                                        map.ellipsoids.centers[lm][None], w[None])
            if not ok[0] or np.count_nonzero(w) < 3:
                break
            hypothesis.pose = Pose(rotation[0], translation[0])
            hypothesis.correspondences = pairs
