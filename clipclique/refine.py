"""Pose refinement: a clique's pose refitted with every observation it brings next to a matching landmark.

A clique holds three or four objects of a crowded desk, a few decimetres apart: their centres
fix the rotation poorly, and a camera a metre or two away then lands half a metre to two metres
off. Moved into the map with that pose, most other observations fall near their own landmarks;
taking every observation that lands within `radius` of a landmark it is similar to (one-to-one,
nearest first) and refitting with all of them pins the pose down. Done `rounds` times per hypothesis.
"""

from __future__ import annotations

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
    """`nearby_pairs` of each pose (a re-ranked frame has fifty): the observations moved by all of them, the
    landmarks within reach of each (`_within_reach`; `landmarks`: a KD-tree of the map's centres, None: built
    when needed), then one compiled one-to-one pass."""
    rotations = np.array([pose.rotation for pose in poses]).reshape(-1, 3, 3)
    translations = np.array([pose.translation for pose in poses]).reshape(-1, 3)
    moved = (np.einsum("bij,kj->bki", rotations, observations.ellipsoids.centers) + translations[:, None]).reshape(-1, 3)
    reach = radius * (1 + 1e-9) + 1e-12  # a hair wider than the strict test below
    point, lm = _within_reach(moved, map.ellipsoids.centers, reach, landmarks)
    distance = np.linalg.norm(moved[point] - map.ellipsoids.centers[lm], axis=-1)  # the dense matrix's very values
    pose, obs = np.divmod(point, len(observations))
    allowed = (distance < radius) & (similarity[obs, lm] > 0)
    pose, obs, lm = pose[allowed], obs[allowed], lm[allowed]
    order = np.lexsort((lm, obs, distance[allowed], pose))  # per pose nearest first, ties by observation, landmark
    pose, obs, lm = pose[order], obs[order], lm[order]
    taken, per_pose = _one_to_one(pose, obs, lm, len(poses), len(observations), len(map))
    pairs, ends = np.column_stack((obs[taken], lm[taken])), np.cumsum(per_pose).tolist()
    return [pairs[start:end] for start, end in zip([0, *ends], ends)]


DENSE_PAIRS = 1 << 18  # up to this many (moved observation, landmark) pairs, every one is tested


def _within_reach(points: np.ndarray, centers: np.ndarray, reach: float,
                  landmarks: cKDTree | None) -> tuple[np.ndarray, np.ndarray]:
    """(point, landmark) index pairs at most `reach` apart, in no particular order: every pair tested by a
    compiled loop for a room-sized map (fifty poses of a frame against 47 landmarks: 61,000 pairs, tens of
    microseconds), a KD-tree join beyond (a map of 47,000 landmarks costs a join, not a distance matrix)."""
    if len(points) * len(centers) <= DENSE_PAIRS:
        return _pairs_within(points, centers, reach)
    tree = cKDTree(centers) if landmarks is None else landmarks
    near = cKDTree(points).sparse_distance_matrix(tree, reach, output_type="ndarray")
    return near["i"].astype(np.int64), near["j"].astype(np.int64)


@njit(cache=True)
def _pairs_within(points, centers, reach):
    """Every (point, centre) index pair at most `reach` apart, tested one by one."""
    point, centre = [], []
    limit = reach * reach
    for p in range(len(points)):
        for c in range(len(centers)):
            dx = points[p, 0] - centers[c, 0]
            dy = points[p, 1] - centers[c, 1]
            dz = points[p, 2] - centers[c, 2]
            if dx * dx + dy * dy + dz * dz <= limit:
                point.append(p)
                centre.append(c)
    return np.array(point, np.int64), np.array(centre, np.int64)


@njit(cache=True)
def _one_to_one(pose, obs, lm, num_poses, num_obs, num_landmarks):
    """Greedy one-to-one pairing of (pose, observation, landmark) candidates in their order: which are taken
    (neither side used yet by that pose) and how many each pose takes."""
    obs_used_by = np.full(num_obs, -1)
    landmark_used_by = np.full(num_landmarks, -1)
    taken = np.zeros(len(pose), np.bool_)
    per_pose = np.zeros(num_poses, np.int64)
    for i in range(len(pose)):
        b, k, n = pose[i], obs[i], lm[i]
        if obs_used_by[k] != b and landmark_used_by[n] != b:
            obs_used_by[k] = b
            landmark_used_by[n] = b
            taken[i] = True
            per_pose[b] += 1
    return taken, per_pose


def refine(hypotheses: list[Hypothesis], observations: Observations, map: Map, similarity: np.ndarray, radius: float,
           weights: PoseWeights, rounds: int = 2, landmarks: cKDTree | None = None) -> None:
    """Each hypothesis's pose and correspondences replaced by the refit on its nearby pairs, in place,
    as long as they are at least as many as it had (a refit never rests on fewer objects). The
    hypotheses still refining are refitted together, one batch per round (a re-ranked frame has fifty).
    `landmarks`: a KD-tree of the map's centres (`nearby_pairs_of`; None: built only where a round needs it)."""
    active = list(hypotheses)
    for _ in range(rounds):
        if not active:
            return
        nearby = nearby_pairs_of([h.pose for h in active], observations, map, similarity, radius, landmarks)
        refits = [(hypothesis, pairs) for hypothesis, pairs in zip(active, nearby)
                  if len(pairs) >= max(3, len(hypothesis.correspondences))]
        if not refits:
            return
        # Hypotheses that found the same pairs refit alike (a row's fit does not depend on the others'):
        # each distinct set is fitted once.
        distinct: dict[bytes, int] = {}
        fitted = np.array([distinct.setdefault(pairs.tobytes(), len(distinct)) for _, pairs in refits])
        sets = [refits[first][1] for first in np.unique(fitted, return_index=True)[1]]
        sizes = np.array([len(pairs) for pairs in sets])
        valid = np.arange(sizes.max()) < sizes[:, None]
        padded = np.zeros((*valid.shape, 2), np.int64)
        padded[valid] = np.concatenate(sets)
        obs, lm = padded[..., 0], padded[..., 1]
        w = valid * correspondence_weights(similarity[obs, lm].ravel(), observations.ellipsoids.axes[obs].reshape(-1, 3),
                                           map.ellipsoids.axes[lm].reshape(-1, 3), weights).reshape(valid.shape)
        rotation, translation, ok = fit_rigid_batch(observations.ellipsoids.centers[obs], map.ellipsoids.centers[lm], w)
        ok &= np.count_nonzero(w, axis=1) >= 3
        rotation, translation, ok = rotation[fitted], translation[fitted], ok[fitted]
        active = []
        for b in np.flatnonzero(ok):
            hypothesis, pairs = refits[b]
            hypothesis.pose = Pose(rotation[b], translation[b])
            hypothesis.correspondences = pairs
            active.append(hypothesis)
