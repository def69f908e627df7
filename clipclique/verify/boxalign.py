"""Pose refinement by box alignment: the map's ellipsoids, projected as conics, fitted to the detection boxes.

Three or four partly seen objects a few decimetres apart fix a pose poorly by their centres (a clique's
fit, clipclique.pose.refine), but the detector's boxes are sharp: a degree of rotation moves every box
by pixels. As OA-SLAM and GOReloc do, each correspondence (observation with a box, landmark) gives
residuals of the landmark's projected outline box (the tangent lines of its dual conic,
clipclique.verify.projection) against the detection box: along each image axis its offset and its size
difference, in units that grow with the box (a map ellipsoid's outline misses a table's box by tens of
pixels, a cup's by two); a side of a detection box cut by the image border says nothing of where the
object ends and is left out, and a pair whose landmark reaches behind the camera at the start leaves the
pose alone. The outline is not the object's box, so the boxes alone would pull a pose of 3-4 pairs to
where those misfits agree: each pair's observed centre against its landmark's stays in the cost as a
prior. A few Levenberg-Marquardt steps on a Cauchy loss (a wrong pair pulls little) move the pose from
where the clique left it: a rotation vector and a translation in the camera's frame, the Jacobian by
forward differences of one projection of the pose and its 6 perturbations. The refined pose is kept only
where its robust cost fell and it moved less than MAX_MOVE_M and MAX_TURN_RAD; otherwise the clique's
pose stays. Measured in docs/methods.md ("precision from the detection boxes").
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from clipclique.types import Camera, Hypothesis, Map, Observations, Pose
from clipclique.verify.projection import _in_front, conic_entries, spreads

MAX_MOVE_M = 1.0  # a refinement that moves the camera farther has found another pose, not refined this one
MAX_TURN_RAD = np.deg2rad(20.0)
BORDER_PX = 2.0  # a detection box side this close to the image border is cut by it
MIN_PAIRS = 3  # a hypothesis with fewer pairs with a box keeps its pose
STEP = 1e-6  # radians / metres: the forward differences' step
CONVERGED = 1e-5  # radians / metres: a step this small ends the refinement
DAMPING = 1e-3  # initial Levenberg-Marquardt damping, relative to the normal matrix's diagonal


def refine_hypotheses(hypotheses: list[Hypothesis], observations: Observations, map: Map, steps: int, scale: float,
                      map_spreads: np.ndarray | None = None, centre_m: float = 0.0, size_weight: float = 1.0,
                      relative: float = 0.0) -> list[Hypothesis]:
    """`hypotheses` with each pose refined by box alignment (at most `steps` LM steps, residuals in units of
    `scale` pixels); a hypothesis without three usable pairs, or whose refinement did not lower its cost or moved
    too far, keeps its pose. Observations without boxes or camera: unchanged. `map_spreads`: the map's
    `projection.spreads` (None: computed here). `centre_m` > 0: each pair's observed centre, moved into the map,
    minus its landmark's, in units of `centre_m` metres, joins the cost (what the clique's pose was fitted to,
    kept as a prior). `size_weight`: where both sides of an axis count, the box's offset and its size along it
    are the residuals, the size's weighed by this (1: the sides as they are; a map ellipsoid's outline is smaller
    than its object's box, so the size pulls the camera nearer). `relative` > 0: a box's residuals are in units of
    sqrt(scale^2 + (relative * its diagonal)^2) pixels (a large object's ellipsoid misses its box by more pixels)."""
    if steps <= 0 or not hypotheses or observations.boxes is None or observations.camera is None:
        return hypotheses
    distinct, of = _distinct(hypotheses)
    problem = _problem(distinct, observations, map, map_spreads)
    if problem is None:
        return hypotheses
    rotations = np.array([h.pose.rotation for h in distinct], np.float64)[problem.rows]
    translations = np.array([h.pose.translation for h in distinct], np.float64)[problem.rows]
    new_rotations, new_translations, start, end = solve(problem, rotations, translations, steps, scale,
                                                        observations.camera, centre_m, size_weight, relative)
    turn = np.arccos(np.clip((np.einsum("hij,hij->h", rotations, new_rotations) - 1) / 2, -1.0, 1.0))
    move = np.linalg.norm(new_translations - translations, axis=1)
    better = (end < start) & (move < MAX_MOVE_M) & (turn < MAX_TURN_RAD)
    poses = {problem.rows[i]: Pose(new_rotations[i], new_translations[i]) for i in np.flatnonzero(better).tolist()}
    out = list(hypotheses)
    for row, h in enumerate(hypotheses):
        if of[row] in poses:
            out[row] = Hypothesis(poses[of[row]], h.correspondences, h.score, h.conditioning, h.verification,
                                  h.confidence)
    return out


def _distinct(hypotheses: list[Hypothesis]) -> tuple[list[Hypothesis], list[int]]:
    """The hypotheses with distinct poses and correspondences, first first, and which of them each one is: two
    in three of a frame's kept hypotheses repeat one before them (cliques refitted to the same pairs)."""
    first: dict[tuple[bytes, bytes, bytes], int] = {}
    distinct, of = [], []
    for h in hypotheses:
        key = (h.pose.rotation.tobytes(), h.pose.translation.tobytes(), np.asarray(h.correspondences).tobytes())
        if key not in first:
            first[key] = len(distinct)
            distinct.append(h)
        of.append(first[key])
    return distinct, of


class Problem:
    """The pairs of the hypotheses that have at least 3 with a box: their landmarks, detection boxes, which sides
    count and observed centres."""

    def __init__(self, rows: np.ndarray, owner: np.ndarray, column: np.ndarray, centers: np.ndarray,
                 spread: np.ndarray, boxes: np.ndarray, sides: np.ndarray, seen: np.ndarray) -> None:
        self.rows = rows  # (H,) the hypotheses refined
        self.owner = owner  # (P,) 0..H-1 the refined hypothesis of each pair
        self.column = column  # (P,) the pair's landmark
        self.centers, self.spread = centers, spread  # (N, 3), (N, 9) the map's centres and spreads
        self.boxes = boxes  # (P, 4) the detection boxes
        self.sides = sides  # (P, 4) float, 1 where the side counts, 0 where the image border cut it
        self.seen = seen  # (P, 3) the observed centres (camera frame)


def _problem(hypotheses: list[Hypothesis], observations: Observations, map: Map,
             map_spreads: np.ndarray | None) -> Problem | None:
    """The `Problem` of the hypotheses' correspondences whose observation has a box (None: no hypothesis
    has 3)."""
    counts = np.array([len(h.correspondences) for h in hypotheses])
    pairs = np.concatenate([np.asarray(h.correspondences, np.int64).reshape(-1, 2) for h in hypotheses])
    owner = np.repeat(np.arange(len(hypotheses)), counts)
    if observations.has_box is not None:
        boxed = observations.has_box[pairs[:, 0]]
        pairs, owner = pairs[boxed], owner[boxed]
    enough = np.bincount(owner, minlength=len(hypotheses)) >= MIN_PAIRS
    if not enough.any():
        return None
    kept = enough[owner]
    pairs, renumber = pairs[kept], np.cumsum(enough) - 1
    camera = observations.camera
    boxes = np.asarray(observations.boxes, np.float64)[pairs[:, 0]]
    sides = (np.abs(boxes - np.array([0.0, 0.0, camera.width, camera.height])) > BORDER_PX).astype(np.float64)
    every = spreads(map.ellipsoids) if map_spreads is None else map_spreads
    return Problem(np.flatnonzero(enough), renumber[owner[kept]], pairs[:, 1],
                   np.ascontiguousarray(map.ellipsoids.centers, np.float64), np.ascontiguousarray(every, np.float64),
                   boxes, sides, np.ascontiguousarray(observations.ellipsoids.centers[pairs[:, 0]], np.float64))


def solve(problem: Problem, rotations: np.ndarray, translations: np.ndarray, steps: int, scale: float,
          camera: Camera, centre_m: float = 0.0, size_weight: float = 1.0,
          relative: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on each hypothesis (`_solve`): the poses (H, 3, 3), (H, 3) and the robust costs at the
    start and the end (H,) (inf where a pair reaches behind the camera at the start: the pose is left alone)."""
    starts = np.searchsorted(problem.owner, np.arange(len(rotations)))
    ends = np.searchsorted(problem.owner, np.arange(len(rotations)), side="right")
    weights = np.array([1.0 / centre_m if centre_m > 0 else 0.0, size_weight])
    diagonal = np.hypot(problem.boxes[:, 2] - problem.boxes[:, 0], problem.boxes[:, 3] - problem.boxes[:, 1])
    units = 1.0 / np.sqrt(scale**2 + (relative * diagonal) ** 2)
    return _solve(problem.centers, problem.spread, problem.column, problem.boxes, problem.sides, units, problem.seen,
                  starts, ends, np.ascontiguousarray(rotations, np.float64),
                  np.ascontiguousarray(translations, np.float64), steps, weights,
                  np.asarray(camera.intrinsics, np.float64), float(camera.width), float(camera.height),
                  float(camera.max_depth))


@njit(cache=True)
def _solve(centers, spread, column, boxes, sides, units, seen, starts, ends, rotations, translations, steps, weights,
           intrinsics, width, height, max_depth):
    """`solve`, compiled: per hypothesis, each step projects its current pose and 6 perturbations of it
    (`conic_entries`) for the Jacobian; a step that raised the cost is undone and the damping
    raised tenfold, one that lowered it kept and the damping cut tenfold (a few numpy calls per step would cost
    more than the arithmetic of a frame's five hypotheses)."""
    count = len(rotations)
    out_rot, out_trans = rotations.copy(), translations.copy()
    start_cost, end_cost = np.full(count, np.inf), np.full(count, np.inf)
    for h in range(count):
        cols = column[starts[h]:ends[h]]
        c, s = centers[cols], spread[cols]
        box, side, x = boxes[starts[h]:ends[h]], sides[starts[h]:ends[h]], seen[starts[h]:ends[h]]
        unit = units[starts[h]:ends[h]]
        rot, trans = rotations[h].copy(), translations[h].copy()
        cost, usable, normal, gradient = _linearize(c, s, box, side, unit, x, rot, trans, weights, intrinsics, width,
                                                    height, max_depth, True)
        if not usable:
            continue
        start_cost[h] = cost
        damping = DAMPING
        for step in range(steps):
            damped = normal.copy()
            for i in range(6):
                damped[i, i] += damping * max(normal[i, i], 1e-12)
            delta = -np.linalg.solve(damped, gradient)
            if np.abs(delta).max() < CONVERGED:
                break
            trial_rot, trial_trans = _move_pose(rot, trans, delta)
            trial_cost, trial_usable, trial_normal, trial_gradient = _linearize(
                c, s, box, side, unit, x, trial_rot, trial_trans, weights, intrinsics, width, height, max_depth,
                step < steps - 1)
            if trial_usable and trial_cost < cost:
                rot, trans, cost, normal, gradient = trial_rot, trial_trans, trial_cost, trial_normal, trial_gradient
                damping *= 0.1
            else:
                damping *= 10.0
        out_rot[h], out_trans[h], end_cost[h] = rot, trans, cost
    return out_rot, out_trans, start_cost, end_cost


@njit(cache=True)
def _move_pose(rotation, translation, delta):
    """A pose moved in its own camera frame by (6,) (rotation vector w, translation d): R exp([w]), t + R d, in
    plain loops (numba's `@` on 3 x 3 matrices calls BLAS, a microsecond each)."""
    turn = _exp(delta[0], delta[1], delta[2])
    moved, shifted = np.empty((3, 3)), translation.copy()
    for i in range(3):
        for j in range(3):
            moved[i, j] = rotation[i, 0] * turn[0, j] + rotation[i, 1] * turn[1, j] + rotation[i, 2] * turn[2, j]
        shifted[i] += rotation[i, 0] * delta[3] + rotation[i, 1] * delta[4] + rotation[i, 2] * delta[5]
    return moved, shifted


@njit(cache=True)
def _exp(x, y, z):
    """The rotation of the rotation vector (x, y, z) (Rodrigues: I + sin a [k] + (1 - cos a) (k k^T - I))."""
    angle = np.sqrt(x * x + y * y + z * z)
    out = np.eye(3)
    if angle < 1e-15:
        return out
    k = np.array([x, y, z]) / angle
    sin, versine = np.sin(angle), 1.0 - np.cos(angle)
    for i in range(3):
        for j in range(3):
            out[i, j] += versine * (k[i] * k[j] - (1.0 if i == j else 0.0))
    out[0, 1] -= sin * k[2]
    out[1, 0] += sin * k[2]
    out[0, 2] += sin * k[1]
    out[2, 0] -= sin * k[1]
    out[1, 2] -= sin * k[0]
    out[2, 1] += sin * k[0]
    return out


@njit(cache=True)
def _linearize(centers, spread, boxes, sides, units, seen, rotation, translation, weights, intrinsics, width, height,
               max_depth, jacobian):
    """At one pose: the Cauchy cost of the pairs' residuals (`_residuals`), whether every landmark is wholly in
    front of the camera, and (when `jacobian`) the normal matrix J^T W J and gradient J^T W r of the reweighted
    residuals (IRLS), J by forward differences."""
    moves = 7 if jacobian else 1
    rots, trans = np.empty((moves, 3, 3)), np.empty((moves, 3))
    for m in range(moves):
        rots[m], trans[m] = rotation, translation
    if jacobian:
        for axis in range(3):  # R exp([STEP e_axis]) and t + STEP R e_axis, without a matrix allocated each
            for i in range(3):
                for j in range(3):
                    rots[1 + axis, i, j] = (rotation[i, 0] * _TURNS[axis, 0, j] + rotation[i, 1] * _TURNS[axis, 1, j]
                                            + rotation[i, 2] * _TURNS[axis, 2, j])
                trans[4 + axis, i] += STEP * rotation[i, axis]
    entries = conic_entries(np.ascontiguousarray(centers.T), np.ascontiguousarray(spread.T), rots, trans,
                            intrinsics)
    size = len(centers)
    residual = np.zeros((moves, size, RESIDUALS))
    for m in range(moves):
        for n in range(size):
            e = m * size + n
            _residuals_into(entries[0, e], entries[1, e], entries[2, e], entries[3, e], entries[4, e], boxes[n],
                            sides[n], units[n], seen[n], centers[n], rots[m], trans[m], weights, residual[m, n])
    usable = True
    for n in range(size):
        usable = usable and _in_front(entries[4, n], entries[5, n]) and entries[5, n] <= max_depth
    cost = 0.0
    normal, gradient = np.zeros((6, 6)), np.zeros(6)
    column = np.empty(6)
    for n in range(size):
        for k in range(RESIDUALS):
            r = residual[0, n, k]
            cost += 0.5 * np.log1p(r * r)
            if jacobian and r != 0.0:
                weight = 1.0 / (1.0 + r * r)  # Cauchy's IRLS weight
                for i in range(6):
                    column[i] = (residual[1 + i, n, k] - r) / STEP
                for i in range(6):
                    gradient[i] += weight * column[i] * r
                    for j in range(6):
                        normal[i, j] += weight * column[i] * column[j]
    return cost, usable, normal, gradient


_TURNS = np.array([Rotation.from_rotvec(STEP * axis).as_matrix() for axis in np.eye(3)])  # exp([STEP e_i])
RESIDUALS = 7  # per pair: four of the box, three of the centre


@njit(cache=True, inline="always")
def _residuals_into(c11, c13, c22, c23, c33, box, sides, unit, seen, center, rotation, translation, weights, out):
    """One pair's residuals under one pose: along each image axis, where both sides count, the outline box's offset
    from the detection box and (times `weights[1]`) its size's difference, both over sqrt 2 (at weight 1 the sum of
    squares of the two sides' differences), where one counts, that side's difference, in units of 1 / `unit`
    pixels; then the observed centre moved into the map minus the landmark's, in units of 1 / `weights[0]` metres
    (zeros at 0)."""
    u0, v0, u1, v1 = _outline(c11, c13, c22, c23, c33)
    scale, centre, size_weight = unit, weights[0], weights[1]
    for axis in range(2):
        low, high = (u0, u1) if axis == 0 else (v0, v1)
        first, second = (low - box[axis]) * scale, (high - box[axis + 2]) * scale
        if sides[axis] > 0 and sides[axis + 2] > 0:
            out[2 * axis] = (first + second) * SQRT_HALF
            out[2 * axis + 1] = (second - first) * SQRT_HALF * size_weight
        else:
            out[2 * axis] = first * sides[axis] + second * sides[axis + 2]
            out[2 * axis + 1] = 0.0
    if centre > 0:
        for i in range(3):
            out[4 + i] = (rotation[i, 0] * seen[0] + rotation[i, 1] * seen[1] + rotation[i, 2] * seen[2]
                          + translation[i] - center[i]) * centre


SQRT_HALF = np.sqrt(0.5)


@njit(cache=True, inline="always")
def _outline(c11, c13, c22, c23, c33):
    """The unclipped outline box (u0, v0, u1, v1) of a dual conic of an ellipsoid in front (C*33 < 0): the
    tangent lines x = u, (1, 0, -u) C* (1, 0, -u)^T = 0, as projection's `_outline_box` before clipping."""
    c33 = c33 if c33 < 0 else -1.0
    root_u = np.sqrt(max(c13 * c13 - c11 * c33, 0.0))
    root_v = np.sqrt(max(c23 * c23 - c22 * c33, 0.0))
    return (c13 + root_u) / c33, (c23 + root_v) / c33, (c13 - root_u) / c33, (c23 - root_v) / c33
