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
from clipclique.pose.fit import (
    WEIGHT_MODES,
    compiled_weighted_sets,
    fit_rigid_batch,
    fit_rigid_sets,
    nonzero_counts,
    weighted_sets,
)
from clipclique.pose.stack import Stack, alike
from clipclique.types import Hypothesis, Map, Observations, Pose


def nearby_pairs(pose: Pose, observations: Observations, map: Map, similarity: np.ndarray, radius: float,
                 landmarks: cKDTree | None = None) -> np.ndarray:
    """(M, 2) (observation, landmark) pairs, one-to-one, nearest first (ties by observation, then
    landmark): each observation moved into the map by `pose` lies within `radius` of a landmark its
    similarity to is positive."""
    return nearby_pairs_of([pose], observations, map, similarity, radius, landmarks)[0]


def nearby_pairs_of(poses: list[Pose], observations: Observations, map: Map, similarity: np.ndarray,
                    radius: float, landmarks: cKDTree | None = None) -> list[np.ndarray]:
    """`nearby_pairs` of each pose (a re-ranked frame has fifty), by `_stacked_nearby_pairs`."""
    rotations = np.array([pose.rotation for pose in poses]).reshape(-1, 3, 3)
    translations = np.array([pose.translation for pose in poses]).reshape(-1, 3)
    pairs, counts = _stacked_nearby_pairs(rotations, translations, observations, map, similarity, radius, landmarks)
    ends = np.cumsum(counts).tolist()
    return [pairs[start:end] for start, end in zip([0, *ends], ends)]


def _stacked_nearby_pairs(rotations: np.ndarray, translations: np.ndarray, observations: Observations, map: Map,
                          similarity: np.ndarray, radius: float,
                          landmarks: cKDTree | None) -> tuple[np.ndarray, np.ndarray]:
    """The nearby pairs of B poses (rotations (B, 3, 3), translations (B, 3)) stacked pose after pose, and (B,)
    how many each has: the observations moved by all of them; for a room-sized map one compiled pass tests each
    point against the landmarks within reach along one axis and picks each pose's nearest one-to-one
    (`_nearest_of_all`: fifty poses of a frame against 47 landmarks); beyond, a KD-tree join lists the pairs nearer
    than `radius` (`_near_pairs`) and one compiled pass picks (a numpy pass each cost more than the work)."""
    moved = _apply_poses(rotations, translations, np.ascontiguousarray(observations.ellipsoids.centers, np.float64))
    centers = map.ellipsoids.centers
    if len(moved) * len(centers) <= DENSE_PAIRS:
        return _nearest_of_all(moved, *_along_widest_axis(np.ascontiguousarray(centers, np.float64)), similarity,
                               radius, len(rotations), len(observations))
    near = _near_pairs(moved, centers, similarity, radius, len(observations), landmarks)
    return _nearest_one_to_one(*near, len(rotations), len(observations), len(map))


@njit(cache=True)
def _apply_poses(rotations, translations, points):
    """(B * K, 3) the K points moved by each of B poses, `np.einsum("bij,kj->bki", rotations, points) +
    translations[:, None]` in one pass (two numpy passes cost more than the arithmetic)."""
    moved = np.empty((len(rotations) * len(points), 3))
    for b in range(len(rotations)):
        for k in range(len(points)):
            for i in range(3):
                moved[b * len(points) + k, i] = (rotations[b, i, 0] * points[k, 0] + rotations[b, i, 1] * points[k, 1]
                                                 + rotations[b, i, 2] * points[k, 2] + translations[b, i])
    return moved


DENSE_PAIRS = 1 << 18  # up to this many (moved observation, landmark) pairs, every one is tested


def _near_pairs(points: np.ndarray, centers: np.ndarray, similarity: np.ndarray, radius: float, num_obs: int,
                landmarks: cKDTree | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(distance, pose, observation, landmark) of every moved observation (point = pose * num_obs +
    observation) nearer than `radius` to a landmark its similarity to is positive, by pose, observation,
    landmark, by a KD-tree join (a map of 47,000 landmarks costs a join, not a distance matrix; `landmarks`: a
    KD-tree of the map's centres, None: built here)."""
    tree = cKDTree(centers) if landmarks is None else landmarks
    join = cKDTree(points).sparse_distance_matrix(tree, _reach(radius), output_type="ndarray")
    point, landmark = join["i"].astype(np.int64), join["j"].astype(np.int64)
    order = np.argsort(point * len(centers) + landmark)
    return _near_pairs_listed(points, centers, similarity, radius, num_obs, point[order], landmark[order])


@njit(cache=True, inline="always")
def _reach(radius):
    """A hair wider than `radius`: a pair beyond it is surely not nearer than `radius`, whatever the rounding."""
    return radius * (1 + 1e-9) + 1e-12


@njit(cache=True)
def _near_pairs_listed(points, centers, similarity, radius, num_obs, point, landmark):
    """`_near_pairs` of the listed (point, landmark) candidates ordered by point, then landmark."""
    distance, pose, obs, lm = (np.empty(len(point)), np.empty(len(point), np.int64), np.empty(len(point), np.int64),
                               np.empty(len(point), np.int64))
    count, limit = 0, _reach(radius) ** 2
    for i in range(len(point)):
        p, n = point[i], landmark[i]
        d = _near(points, p, centers, n, limit, radius)
        if d >= 0 and similarity[p % num_obs, n] > 0:
            distance[count], pose[count], obs[count], lm[count] = d, p // num_obs, p % num_obs, n
            count += 1
    return distance[:count], pose[:count], obs[:count], lm[:count]


@njit(cache=True, inline="always")
def _near(points, p, centers, n, limit, radius):
    """The distance of points[p] and centers[n] where it is below `radius`, else -1, its square root taken only
    within `limit`, `_reach` squared (most pairs of a map are far). Indices, not rows: a row is an array view,
    counted in and out per pair."""
    dx = points[p, 0] - centers[n, 0]
    dy = points[p, 1] - centers[n, 1]
    dz = points[p, 2] - centers[n, 2]
    squared = dx * dx + dy * dy + dz * dz
    if squared <= limit:
        d = np.sqrt(squared)
        if d < radius:
            return d
    return -1.0


@njit(cache=True)
def _along_widest_axis(centers):
    """The map's centres as `_nearest_of_all` reads them: (3, N') their x, y and z in order along the axis they spread
    most on (finite ones), that axis, and (N',) the landmark of each column; a centre without a place along it (NaN)
    is near nothing and left out (numba's argsort puts NaN last). Four arrays where numpy's expressions took a dozen:
    a room's refinement computes it once per query."""
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    for n in range(len(centers)):
        for i in range(3):
            if np.isfinite(centers[n, i]):
                low[i], high[i] = min(low[i], centers[n, i]), max(high[i], centers[n, i])
    axis = 0  # np.argmax's: the first widest
    for i in (1, 2):
        if high[i] - low[i] > high[axis] - low[axis]:
            axis = i
    keys = np.empty(len(centers))
    placed = 0
    for n in range(len(centers)):
        keys[n] = centers[n, axis]
        placed += not np.isnan(keys[n])
    order = np.argsort(keys)[:placed]
    by_axis = np.empty((3, placed))
    for column in range(placed):
        for i in range(3):
            by_axis[i, column] = centers[order[column], i]
    return by_axis, axis, order


@njit(cache=True)
def _nearest_of_all(points, by_axis, axis, landmark_of, similarity, radius, num_poses, num_obs):
    """`_nearest_one_to_one` of the near pairs of every point and every centre, pose after pose, with no list of all
    poses' pairs in between. by_axis, axis, landmark_of: `_along_widest_axis`. Each point meets only the centres
    whose coordinate along `axis` differs from its own by at most a hair beyond `_reach` (a fifth of a desk's,
    found by bisection): that difference is the very one the distance squares, and one beyond it squares past
    `_reach` squared whatever the rounding, so no near pair is missed. The distance as `_near` computes it."""
    size = len(landmark_of)
    distance, lm = np.empty(num_obs * size), np.empty(num_obs * size, np.int64)
    firsts, ends = np.empty(num_obs, np.int64), np.empty(num_obs, np.int64)
    nearest, nearest_landmark, live = np.empty(num_obs), np.empty(num_obs, np.int64), np.empty(num_obs, np.int64)
    pairs = np.empty((num_poses * min(num_obs, size), 2), np.int64)
    per_pose = np.zeros(num_poses, np.int64)
    landmark_used_by = np.full(similarity.shape[1], -1)
    keys, limit = by_axis[axis], _reach(radius) ** 2
    bound, count = _reach(_reach(radius)), 0  # a hair beyond reach: a difference past it squares past `limit`
    for b in range(num_poses):
        near = 0
        for k in range(num_obs):
            x, y, z = points[b * num_obs + k, 0], points[b * num_obs + k, 1], points[b * num_obs + k, 2]
            key = points[b * num_obs + k, axis]
            low, high = 0, size  # the first centre not beyond `bound` below the point (NaN: none is)
            while low < high:
                middle = (low + high) >> 1
                if key - keys[middle] > bound:
                    low = middle + 1
                else:
                    high = middle
            firsts[k] = near
            for i in range(low, size):
                if not key - keys[i] >= -bound:
                    break
                dx, dy, dz = x - by_axis[0, i], y - by_axis[1, i], z - by_axis[2, i]
                squared = dx * dx + dy * dy + dz * dz
                if squared <= limit:
                    d, n = np.sqrt(squared), landmark_of[i]
                    if d < radius and similarity[k, n] > 0:
                        distance[near], lm[near] = d, n
                        near += 1
            ends[k] = near
        taken = _take_nearest(distance, lm, firsts, ends, nearest, nearest_landmark, live, b, landmark_used_by, pairs,
                              count)
        per_pose[b], count = taken - count, taken
    return pairs[:count].copy(), per_pose


@njit(cache=True)
def _nearest_one_to_one(distance, pose, obs, lm, num_poses, num_obs, num_landmarks):
    """Near pairs ordered by pose, observation, landmark -> per pose nearest first (ties by observation, then
    landmark) and one-to-one: (M, 2) (observation, landmark) pose after pose, and (B,) how many each pose took
    (`_take_nearest` per pose)."""
    first = np.searchsorted(pose, np.arange(num_poses + 1))
    firsts, ends = np.empty(num_obs, np.int64), np.empty(num_obs, np.int64)
    nearest, nearest_landmark, live = np.empty(num_obs), np.empty(num_obs, np.int64), np.empty(num_obs, np.int64)
    pairs = np.empty((len(pose), 2), np.int64)
    per_pose = np.zeros(num_poses, np.int64)
    landmark_used_by = np.full(num_landmarks, -1)
    count = 0
    for b in range(num_poses):
        firsts[:], ends[:] = 0, 0
        for i in range(first[b], first[b + 1]):
            if ends[obs[i]] == 0:
                firsts[obs[i]] = i
            ends[obs[i]] = i + 1
        taken = _take_nearest(distance, lm, firsts, ends, nearest, nearest_landmark, live, b, landmark_used_by, pairs,
                              count)
        per_pose[b], count = taken - count, taken
    return pairs[:count].copy(), per_pose


@njit(cache=True, inline="always")
def _take_nearest(distance, lm, firsts, ends, nearest, nearest_landmark, live, pose, landmark_used_by, pairs,
                  count):
    """Pose `pose`'s near pairs taken nearest first, ties by observation, then landmark, each where neither side is
    used yet, written to `pairs` from row `count`; the rows written up to. Observation k's near pairs are
    distance[firsts[k]: ends[k]] and lm[...], in any order (`landmark_used_by`: the last pose that used each
    landmark; nearest, nearest_landmark: scratch). The greedy over all pairs sorted, without the sort: it takes
    the least pair whose sides are both free, which is the least of each free observation's nearest free
    landmark; after a take only the observations whose nearest was that landmark look again. An observation taken
    or left without a free landmark never looks again, so each pass reads only those still `live` (scratch, in
    order: a tie keeps the first). Inlined into its callers, as `_near`: its arrays are not counted in and out per
    pose."""
    alive = 0
    for k in range(len(firsts)):
        nearest[k], nearest_landmark[k] = _nearest_free(distance, lm, firsts[k], ends[k], pose, landmark_used_by)
        if nearest[k] < np.inf:
            live[alive] = k
            alive += 1
    while True:
        best, least, kept = -1, np.inf, 0
        for i in range(alive):
            k = live[i]
            if nearest[k] < np.inf:
                live[kept] = k
                kept += 1
                if nearest[k] < least:  # a tie keeps the first observation
                    best, least = k, nearest[k]
        alive = kept
        if best < 0:
            return count
        taken = nearest_landmark[best]
        landmark_used_by[taken], nearest[best] = pose, np.inf
        pairs[count, 0], pairs[count, 1] = best, taken
        count += 1
        for i in range(alive):
            k = live[i]
            if nearest_landmark[k] == taken and nearest[k] < np.inf:
                nearest[k], nearest_landmark[k] = _nearest_free(distance, lm, firsts[k], ends[k], pose,
                                                                landmark_used_by)


@njit(cache=True, inline="always")
def _nearest_free(distance, lm, start, stop, pose, landmark_used_by):
    """The least (distance, landmark) of distance[start: stop] and lm[...] whose landmark `pose` has not used;
    (inf, -1) where none is (a near pair's distance is below the radius, finite)."""
    least, landmark = np.inf, -1
    for i in range(start, stop):
        if (distance[i] < least or (distance[i] == least and lm[i] < landmark)) and landmark_used_by[lm[i]] != pose:
            least, landmark = distance[i], lm[i]
    return least, landmark


def refine(hypotheses: list[Hypothesis], observations: Observations, map: Map, similarity: np.ndarray, radius: float,
           weights: PoseWeights, rounds: int = 2, landmarks: cKDTree | None = None) -> None:
    """Each hypothesis's pose and correspondences replaced by the refit on its nearby pairs, in place
    (`refine_stack` of their stack)."""
    stack, moved = refine_stack(Stack.of(hypotheses), observations, map, similarity, radius, weights, rounds, landmarks)
    ends = np.cumsum(stack.counts)
    for i in np.flatnonzero(moved).tolist():
        hypotheses[i].pose = Pose(stack.rotations[i], stack.translations[i])
        hypotheses[i].correspondences = stack.pairs[ends[i] - stack.counts[i]: ends[i]]


def refine_stack(stack: Stack, observations: Observations, map: Map, similarity: np.ndarray, radius: float,
                 weights: PoseWeights, rounds: int = 2, landmarks: cKDTree | None = None) -> tuple[Stack, np.ndarray]:
    """The stack with each hypothesis's pose and pairs replaced by the refit on its nearby pairs, as long as
    they are at least as many as it had (a refit never rests on fewer objects), `rounds` times; and (B,)
    which were replaced. The hypotheses still refining are refitted together, one batch per round (a
    re-ranked frame has fifty). A room-sized map is refined in one compiled call (`_refine_densely`; a dozen
    Python-level calls a round cost as much as the work), a larger one round by round (`_refine_by_rounds`).
    `landmarks`: a KD-tree of the map's centres (`nearby_pairs_of`; None: built only where a round needs it)."""
    if len(stack) * len(observations) * len(map) <= DENSE_PAIRS:
        rotations, translations, sizes, pairs, moved, any_moved = _refine_densely(
            stack.rotations, stack.translations, stack.counts, stack.pairs,
            np.ascontiguousarray(observations.ellipsoids.centers, np.float64), observations.ellipsoids.axes,
            np.ascontiguousarray(map.ellipsoids.centers, np.float64), map.ellipsoids.axes, similarity, radius,
            WEIGHT_MODES[weights], rounds)
        return (Stack(rotations=rotations, translations=translations, pairs=pairs, counts=sizes, scores=stack.scores,
                      conditioning=stack.conditioning) if any_moved else stack), moved
    return _refine_by_rounds(stack, observations, map, similarity, radius, weights, rounds, landmarks)


def _refine_by_rounds(stack: Stack, observations: Observations, map: Map, similarity: np.ndarray, radius: float,
                      weights: PoseWeights, rounds: int, landmarks: cKDTree | None) -> tuple[Stack, np.ndarray]:
    """`refine_stack`, a round at a time: the nearby pairs of each by `_stacked_nearby_pairs` (a KD-tree join beyond a
    room-sized map) and the fits by `fit_rigid_batch`."""
    rotations, translations, sizes = stack.rotations.copy(), stack.translations.copy(), stack.counts.copy()
    found = [stack.pairs]  # every round's pairs after the stack's own; `origin` indexes them all, joined
    origin, offset = stack.starts(), len(stack.pairs)
    moved = np.zeros(len(stack), bool)
    active = np.arange(len(stack))
    for _ in range(rounds):
        if not len(active):
            break
        pairs, counts = _stacked_nearby_pairs(rotations[active], translations[active], observations, map, similarity,
                                              radius, landmarks)
        starts, refits = _refitting(counts, sizes[active])
        if not len(refits):
            break
        # Hypotheses that found the same pairs refit alike (a row's fit does not depend on the others'):
        # each distinct set is fitted once.
        fitted, firsts = alike(np.zeros((len(refits), 0)), pairs, starts[refits], counts[refits])
        firsts = refits[firsts]
        rotation, translation, ok = _refit(pairs, starts[firsts], counts[firsts], observations, map, similarity,
                                           weights)
        active = _survivors(rotation, translation, ok, fitted, refits, active, starts, offset, counts, rotations,
                            translations, sizes, origin, moved)
        found.append(pairs)
        offset += len(pairs)
    if not moved.any():
        return stack, moved
    gather = np.repeat(origin - (np.cumsum(sizes) - sizes), sizes) + np.arange(sizes.sum())
    return Stack(rotations=rotations, translations=translations, pairs=np.concatenate(found)[gather], counts=sizes,
                 scores=stack.scores, conditioning=stack.conditioning), moved


@njit(cache=True)
def _refine_densely(rotations, translations, counts, pairs, centers, axes, landmark_centers, landmark_axes,
                    similarity, radius, mode, rounds):
    """`_refine_by_rounds` of a room-sized map in one pass: new rotations, translations, counts and pairs (the
    stack's arrays), which hypotheses moved and whether any did (numpy's `any` costs more than the pass). Each round
    as `_refine_by_rounds` takes it: `_nearest_of_all`, `_refitting`, the distinct sets fitted (`_chosen_pairs`,
    `compiled_weighted_sets`, their fit) and `_survivors`; but a set fitted in an earlier round is not fitted again
    (`_known_sets`): a set's fit is its own (`_pad`), and a hypothesis whose refit found the pairs it was just fitted
    to, or another's, would only be given that fit again (a third of a room's second-round refits)."""
    rotations, translations, sizes = rotations.copy(), translations.copy(), counts.copy()
    num_obs, (by_axis, axis, landmark_of) = len(centers), _along_widest_axis(landmark_centers)
    found = np.empty((len(pairs) + rounds * len(sizes) * min(num_obs, len(landmark_centers)), 2), np.int64)
    found[:len(pairs)] = pairs
    origin, offset = np.cumsum(sizes) - sizes, len(pairs)
    moved = np.zeros(len(sizes), np.bool_)
    active = np.arange(len(sizes))
    pad_observation, pad_landmark = _pad(centers), _pad(landmark_centers)
    # every set fitted so far: where it lies in `found`, its pose and whether it has one
    set_starts, set_counts = np.empty(rounds * len(sizes), np.int64), np.empty(rounds * len(sizes), np.int64)
    set_rotations, set_translations = np.empty((rounds * len(sizes), 3, 3)), np.empty((rounds * len(sizes), 3))
    set_ok, known = np.empty(rounds * len(sizes), np.bool_), 0
    for _ in range(rounds):
        if not len(active):
            break
        near, near_counts = _nearest_of_all(_apply_poses(rotations[active], translations[active], centers), by_axis,
                                            axis, landmark_of, similarity, radius, len(active), num_obs)
        starts, refits = _refitting(near_counts, sizes[active])
        if not len(refits):
            break
        found[offset: offset + len(near)] = near
        fitted, fresh = _known_sets(found, offset + starts[refits], near_counts[refits], set_starts, set_counts, known)
        new = refits[fresh]
        chosen, scores = _chosen_pairs(near, starts[new], near_counts[new], similarity)
        source, target, w = compiled_weighted_sets(chosen, scores.astype(np.float64), near_counts[new],
                                                   pad_observation, pad_landmark, 0.0, centers, axes,
                                                   landmark_centers, landmark_axes, mode)
        rotation, translation, ok = fit_rigid_sets(w, source, target)
        ok &= nonzero_counts(w) >= 3
        for i in range(len(new)):
            s = known + i
            set_starts[s], set_counts[s], set_ok[s] = offset + starts[new[i]], near_counts[new[i]], ok[i]
            for j in range(3):  # number by number: row views are counted in and out
                set_translations[s, j] = translation[i, j]
                for k in range(3):
                    set_rotations[s, j, k] = rotation[i, j, k]
        known += len(new)
        active = _survivors(set_rotations, set_translations, set_ok, fitted, refits, active, starts, offset,
                            near_counts, rotations, translations, sizes, origin, moved)
        offset += len(near)
    joined = np.empty((sizes.sum(), 2), np.int64)
    row = 0
    for b in range(len(sizes)):
        for i in range(origin[b], origin[b] + sizes[b]):
            joined[row, 0], joined[row, 1] = found[i, 0], found[i, 1]
            row += 1
    return rotations, translations, sizes, joined, moved, moved.any()


@njit(cache=True)
def _known_sets(found: np.ndarray, starts: np.ndarray, counts: np.ndarray, set_starts: np.ndarray,
                set_counts: np.ndarray, known: int) -> tuple[np.ndarray, np.ndarray]:
    """Of the sets found[starts[r]: starts[r] + counts[r]]: (R,) which set each is, numbered among the `known`
    (found[set_starts[s]: set_starts[s] + set_counts[s]], all distinct) and then the new ones in order of first
    appearance; and (R',) the first of each new one. Sets are alike where they hold the same pairs in the same
    order, compared by index in place (a row handed to a helper is a view, counted in and out)."""
    fitted, fresh = np.empty(len(starts), np.int64), np.empty(len(starts), np.int64)
    new = 0
    for r in range(len(starts)):
        fitted[r] = -1
        for s in range(known):
            if _same_rows(found, set_starts[s], set_counts[s], starts[r], counts[r]):
                fitted[r] = s
                break
        for i in range(new if fitted[r] < 0 else 0):
            if _same_rows(found, starts[fresh[i]], counts[fresh[i]], starts[r], counts[r]):
                fitted[r] = known + i
                break
        if fitted[r] < 0:
            fitted[r], fresh[new] = known + new, r
            new += 1
    return fitted, fresh[:new].copy()


@njit(cache=True, inline="always")
def _same_rows(rows: np.ndarray, first: int, first_count: int, second: int, second_count: int) -> bool:
    """Whether rows[first: first + first_count] and rows[second: second + second_count] of an (M, 2) array are the
    same rows in the same order."""
    if first_count != second_count:
        return False
    for i in range(first_count):
        if rows[first + i, 0] != rows[second + i, 0] or rows[first + i, 1] != rows[second + i, 1]:
            return False
    return True


@njit(cache=True)
def _pad(points: np.ndarray) -> int:
    """The first point (row) whose coordinates are all finite (0 where none is): what a batch fit pads its shorter
    sets with, at weight 0. A finite pad adds zeros to every sum of a fit, so that a set's pose does not depend on
    the sets fitted beside it (a NaN pad made every padded set of its batch degenerate)."""
    for k in range(len(points)):
        if np.isfinite(points[k, 0]) and np.isfinite(points[k, 1]) and np.isfinite(points[k, 2]):
            return k
    return 0


def _refit(pairs: np.ndarray, starts: np.ndarray, counts: np.ndarray, observations: Observations, map: Map,
           similarity: np.ndarray, weights: PoseWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The weighted pose of each set `pairs[start: start + count]`, fitted in one batch (shorter sets padded
    with a pair of finite centres at weight 0, `_pad`), and whether it has a pose (at least 3 positive weights, not
    collinear)."""
    chosen, scores = _chosen_pairs(pairs, starts, counts, similarity)
    pad = (_pad(np.ascontiguousarray(observations.ellipsoids.centers, np.float64)),
           _pad(np.ascontiguousarray(map.ellipsoids.centers, np.float64)), 0.0)
    source, target, w = weighted_sets(chosen, scores, counts, pad,
                                      (observations.ellipsoids.centers, observations.ellipsoids.axes),
                                      (map.ellipsoids.centers, map.ellipsoids.axes), weights)
    rotation, translation, ok = fit_rigid_batch(source, target, w)
    return rotation, translation, ok & (nonzero_counts(w) >= 3)


@njit(cache=True)
def _refitting(counts: np.ndarray, sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B,) where each pose's nearby pairs begin among all (`counts[b]` each), and the poses that refit: those
    with at least 3 pairs and no fewer than they hold (`sizes`), in order. One pass for numpy's
    `np.cumsum(counts) - counts` and `np.flatnonzero(counts >= np.maximum(3, sizes))` (a call costs more than
    the work)."""
    starts, refits = np.empty(len(counts), np.int64), np.empty(len(counts), np.int64)
    start, found = 0, 0
    for b in range(len(counts)):
        starts[b] = start
        start += counts[b]
        if counts[b] >= max(3, sizes[b]):
            refits[found] = b
            found += 1
    return starts, refits[:found].copy()


@njit(cache=True)
def _chosen_pairs(pairs: np.ndarray, starts: np.ndarray, counts: np.ndarray,
                  similarity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sets pairs[start: start + count] one after another (M, 2), and (M,) each pair's similarity: numpy's
    `pairs[np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())]` and
    `similarity[chosen[:, 0], chosen[:, 1]]` in one pass."""
    chosen = np.empty((counts.sum(), 2), np.int64)
    scores = np.empty(counts.sum(), similarity.dtype)
    row = 0
    for b in range(len(counts)):
        for i in range(starts[b], starts[b] + counts[b]):
            chosen[row, 0], chosen[row, 1] = pairs[i, 0], pairs[i, 1]
            scores[row] = similarity[pairs[i, 0], pairs[i, 1]]
            row += 1
    return chosen, scores


@njit(cache=True)
def _survivors(rotation, translation, ok, fitted, refits, active, starts, offset, counts, rotations, translations,
               sizes, origin, moved):
    """A round's refits taken where their set has a pose (`ok[fitted[r]]`): hypothesis `active[refits[r]]` gets the
    pose of its set, `counts[refits[r]]` pairs from `offset + starts[refits[r]]` on and is marked moved, in place; the
    hypotheses taken, in order (those still refining). numpy's masks and fancy assignments in one pass."""
    taken = np.empty(len(refits), np.int64)
    count = 0
    for r in range(len(refits)):
        f = fitted[r]
        if ok[f]:
            a = active[refits[r]]
            for i in range(3):  # number by number: row views are counted in and out
                translations[a, i] = translation[f, i]
                for j in range(3):
                    rotations[a, i, j] = rotation[f, i, j]
            sizes[a], origin[a], moved[a] = counts[refits[r]], offset + starts[refits[r]], True
            taken[count] = a
            count += 1
    return taken[:count].copy()
