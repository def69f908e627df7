"""Pose refinement by box alignment: the map's ellipsoids, projected as conics, fitted to the detection boxes.

Three or four partly seen objects a few decimetres apart fix a pose poorly by their centres (a clique's
fit, clipclique.pose.refine), but the detector's boxes are sharp: a degree of rotation moves every box
by pixels. As OA-SLAM and GOReloc do, each correspondence (observation with a box, landmark) gives four
residuals, the landmark's projected outline box (the tangent lines of its dual conic,
clipclique.verify.projection) minus the detection box, in units of `scale` pixels; a side of a
detection box cut by the image border says nothing of where the object ends and is left out, and so
is a pair whose landmark reaches behind the camera at the start. A few Levenberg-Marquardt steps on a
Cauchy loss (a wrong pair or a badly fitted ellipsoid pulls little) move the pose from where the clique
left it: a rotation vector and a translation in the camera's frame, the Jacobian by central differences
of one batched projection of every hypothesis's 13 poses. The refined pose is kept only where its robust
cost fell and it moved less than MAX_MOVE_M and MAX_TURN_RAD; otherwise the clique's pose stays.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from clipclique.types import Camera, Hypothesis, Map, Observations, Pose
from clipclique.verify.projection import _projected, spreads

MAX_MOVE_M = 1.0  # a refinement that moves the camera farther has found another pose, not refined this one
MAX_TURN_RAD = np.deg2rad(20.0)
BORDER_PX = 2.0  # a detection box side this close to the image border is cut by it
STEP = 1e-5  # radians / metres: the central differences' step
DAMPING = 1e-3  # initial Levenberg-Marquardt damping, relative to the normal matrix's diagonal


def refined(hypotheses: list[Hypothesis], observations: Observations, map: Map, steps: int, scale: float,
            map_spreads: np.ndarray | None = None) -> list[Hypothesis]:
    """`hypotheses` with each pose refined by box alignment (at most `steps` LM steps, residuals in units of
    `scale` pixels); a hypothesis without three usable pairs, or whose refinement did not lower its cost or moved
    too far, keeps its pose. Observations without boxes or camera: unchanged. `map_spreads`: the map's
    `projection.spreads` (None: computed here)."""
    if steps <= 0 or not hypotheses or observations.boxes is None or observations.camera is None:
        return hypotheses
    problem = _problem(hypotheses, observations, map, map_spreads)
    if problem is None:
        return hypotheses
    rotations = np.array([h.pose.rotation for h in hypotheses], np.float64)[problem.rows]
    translations = np.array([h.pose.translation for h in hypotheses], np.float64)[problem.rows]
    new_rotations, new_translations, start, end = solve(problem, rotations, translations, steps, scale,
                                                        observations.camera)
    out = list(hypotheses)
    for i, row in enumerate(problem.rows.tolist()):
        turn = np.arccos(np.clip((np.trace(rotations[i].T @ new_rotations[i]) - 1) / 2, -1.0, 1.0))
        move = np.linalg.norm(new_translations[i] - translations[i])
        if end[i] < start[i] and move < MAX_MOVE_M and turn < MAX_TURN_RAD:
            h = hypotheses[row]
            out[row] = Hypothesis(Pose(new_rotations[i], new_translations[i]), h.correspondences, h.score,
                                  h.conditioning, h.verification, h.confidence)
    return out


class Problem:
    """The pairs of the hypotheses that have at least 3 with a box: their landmarks (as columns of one
    projection), detection boxes and which sides count."""

    def __init__(self, rows: np.ndarray, owner: np.ndarray, column: np.ndarray, centers: np.ndarray,
                 spread: np.ndarray, boxes: np.ndarray, sides: np.ndarray) -> None:
        self.rows = rows  # (H,) the hypotheses refined
        self.owner = owner  # (P,) 0..H-1 the refined hypothesis of each pair
        self.column = column  # (P,) the pair's landmark among the projected ones
        self.centers, self.spread = centers, spread  # (U, 3), (U, 9) the landmarks projected
        self.boxes = boxes  # (P, 4) the detection boxes
        self.sides = sides  # (P, 4) float, 1 where the side counts, 0 where the image border cut it


def _problem(hypotheses: list[Hypothesis], observations: Observations, map: Map,
             map_spreads: np.ndarray | None) -> Problem | None:
    """The `Problem` of the hypotheses' correspondences whose observation has a box (None: no hypothesis
    has 3)."""
    has_box = np.ones(len(observations), bool) if observations.has_box is None else observations.has_box
    pairs, owners, rows = [], [], []
    for row, h in enumerate(hypotheses):
        corr = np.asarray(h.correspondences, np.int64).reshape(-1, 2)
        corr = corr[has_box[corr[:, 0]]]
        if len(corr) >= 3:
            pairs.append(corr)
            owners.append(np.full(len(corr), len(rows)))
            rows.append(row)
    if not rows:
        return None
    pairs, owner = np.concatenate(pairs), np.concatenate(owners)
    landmarks, column = np.unique(pairs[:, 1], return_inverse=True)
    camera = observations.camera
    boxes = np.asarray(observations.boxes, np.float64)[pairs[:, 0]]
    limits = np.array([0.0, 0.0, camera.width, camera.height])
    sides = (np.abs(boxes - limits) > BORDER_PX).astype(np.float64)
    every = spreads(map.ellipsoids) if map_spreads is None else map_spreads
    return Problem(np.array(rows), owner, column.reshape(-1), np.ascontiguousarray(map.ellipsoids.centers[landmarks]),
                   np.ascontiguousarray(every[landmarks]), boxes, sides)


def solve(problem: Problem, rotations: np.ndarray, translations: np.ndarray, steps: int, scale: float,
          camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on each hypothesis (`_solve`): the poses (H, 3, 3), (H, 3) and the robust costs at the
    start and the end (H,) (inf where a pair reaches behind the camera at the start: the pose is left alone)."""
    starts = np.searchsorted(problem.owner, np.arange(len(rotations)))
    ends = np.searchsorted(problem.owner, np.arange(len(rotations)), side="right")
    return _solve(problem.centers, problem.spread, problem.column, problem.boxes / scale, problem.sides, starts, ends,
                  np.ascontiguousarray(rotations, np.float64), np.ascontiguousarray(translations, np.float64), steps,
                  scale, np.asarray(camera.intrinsics, np.float64), float(camera.width), float(camera.height),
                  float(camera.max_depth))


@njit(cache=True)
def _solve(centers, spread, column, boxes, sides, starts, ends, rotations, translations, steps, scale, intrinsics,
           width, height, max_depth):
    """`solve`, compiled: per hypothesis, each step projects its current pose and 12 perturbations of it
    (projection's `_projected`, one call) for the Jacobian; a step that raised the cost is undone and the damping
    raised tenfold, one that lowered it kept and the damping cut tenfold (a few numpy calls per step would cost
    more than the arithmetic of a frame's five hypotheses)."""
    count = len(rotations)
    out_rot, out_trans = rotations.copy(), translations.copy()
    start_cost, end_cost = np.full(count, np.inf), np.full(count, np.inf)
    for h in range(count):
        cols = column[starts[h]:ends[h]]
        c, s = centers[cols], spread[cols]
        box, side = boxes[starts[h]:ends[h]], sides[starts[h]:ends[h]]
        rot, trans = rotations[h].copy(), translations[h].copy()
        cost, usable, normal, gradient = _linearized(c, s, box, side, rot, trans, scale, intrinsics, width, height,
                                                     max_depth, True)
        if not usable:
            continue
        start_cost[h] = cost
        damping = DAMPING
        for step in range(steps):
            damped = normal.copy()
            for i in range(6):
                damped[i, i] += damping * max(normal[i, i], 1e-12)
            delta = -np.linalg.solve(damped, gradient)
            trial_rot, trial_trans = _moved_one(rot, trans, delta)
            trial_cost, trial_usable, trial_normal, trial_gradient = _linearized(
                c, s, box, side, trial_rot, trial_trans, scale, intrinsics, width, height, max_depth, step < steps - 1)
            if trial_usable and trial_cost < cost:
                rot, trans, cost, normal, gradient = trial_rot, trial_trans, trial_cost, trial_normal, trial_gradient
                damping *= 0.1
            else:
                damping *= 10.0
        out_rot[h], out_trans[h], end_cost[h] = rot, trans, cost
    return out_rot, out_trans, start_cost, end_cost


@njit(cache=True)
def _moved_one(rotation, translation, delta):
    """A pose moved in its own camera frame by (6,) (rotation vector w, translation d): R exp([w]), t + R d."""
    return rotation @ _exp(delta[0], delta[1], delta[2]), translation + rotation @ delta[3:]


@njit(cache=True)
def _exp(x, y, z):
    """The rotation of the rotation vector (x, y, z) (Rodrigues)."""
    angle = np.sqrt(x * x + y * y + z * z)
    out = np.eye(3)
    if angle < 1e-15:
        return out
    x, y, z = x / angle, y / angle, z / angle
    sin, cos = np.sin(angle), 1.0 - np.cos(angle)
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return out + sin * cross + cos * (cross @ cross)


@njit(cache=True)
def _linearized(centers, spread, boxes, sides, rotation, translation, scale, intrinsics, width, height, max_depth,
                jacobian):
    """At one pose: the Cauchy cost of the pairs' residuals (projected outline box / scale minus detection box /
    scale, on the sides that count), whether every landmark is wholly in front of the camera, and (when
    `jacobian`) the normal matrix J^T W J and gradient J^T W r of the reweighted residuals (IRLS), J by central
    differences."""
    moves = 13 if jacobian else 1
    rots, trans = np.empty((moves, 3, 3)), np.empty((moves, 3))
    delta = np.zeros(6)
    rots[0], trans[0] = rotation, translation
    for m in range(1, moves):
        delta[:] = 0.0
        delta[(m - 1) % 6] = STEP if m <= 6 else -STEP
        rots[m], trans[m] = _moved_one(rotation, translation, delta)
    conics, _, _, _, full_areas = _projected(centers, spread, rots, trans, intrinsics, width, height, max_depth)
    size = len(centers)
    residual = np.empty((moves, size, 4))
    for m in range(moves):
        for n in range(size):
            conic = conics[m, n]
            u0, v0, u1, v1 = _outline(conic[0, 0], conic[0, 2], conic[1, 1], conic[1, 2], conic[2, 2])
            residual[m, n, 0] = (u0 / scale - boxes[n, 0]) * sides[n, 0]
            residual[m, n, 1] = (v0 / scale - boxes[n, 1]) * sides[n, 1]
            residual[m, n, 2] = (u1 / scale - boxes[n, 2]) * sides[n, 2]
            residual[m, n, 3] = (v1 / scale - boxes[n, 3]) * sides[n, 3]
    usable = True
    for n in range(size):
        usable = usable and full_areas[0, n] > 0
    cost = 0.0
    normal, gradient = np.zeros((6, 6)), np.zeros(6)
    column = np.empty(6)
    for n in range(size):
        for k in range(4):
            r = residual[0, n, k]
            cost += 0.5 * np.log1p(r * r)
            if jacobian:
                weight = 1.0 / (1.0 + r * r)  # Cauchy's IRLS weight
                for i in range(6):
                    column[i] = (residual[1 + i, n, k] - residual[7 + i, n, k]) / (2 * STEP)
                for i in range(6):
                    gradient[i] += weight * column[i] * r
                    for j in range(6):
                        normal[i, j] += weight * column[i] * column[j]
    return cost, usable, normal, gradient


@njit(cache=True, inline="always")
def _outline(c11, c13, c22, c23, c33):
    """The unclipped outline box (u0, v0, u1, v1) of a dual conic of an ellipsoid in front (C*33 < 0): the
    tangent lines x = u, (1, 0, -u) C* (1, 0, -u)^T = 0, as projection's `_outline_box` before clipping."""
    c33 = c33 if c33 < 0 else -1.0
    root_u = np.sqrt(max(c13 * c13 - c11 * c33, 0.0))
    root_v = np.sqrt(max(c23 * c23 - c22 * c33, 0.0))
    return (c13 + root_u) / c33, (c23 + root_v) / c33, (c13 - root_u) / c33, (c23 - root_v) / c33
