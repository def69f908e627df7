"""Ellipsoid fits from point sets, rigid-transform helpers and pose errors.

The ellipsoid of an object is the one inscribed in its PCA oriented bounding box: centre = box
centre, semi-axes = half the box extents, rotation = the principal axes of the points (the
eigenvectors of their covariance). Statistical outlier removal first cuts points whose mean
distance to their `outlier_neighbors` nearest neighbours exceeds the cloud's mean of that by
`outlier_std_ratio` standard deviations. For a free point set (the map builder's fused
instances) the neighbours come from a KD-tree; for one view's depth pixels
(`fit_ellipsoid_depth`) from the pixel's image window, where the nearest 3D neighbours of a
depth pixel lie, in compiled code: about 30x faster than the KD-tree search open3d used
(README, Benchmarks).
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from clipclique.config import FitParams
from clipclique.types import Ellipsoids, Pose


def fit_ellipsoid(points: np.ndarray,
                  params: FitParams = FitParams()) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(center, semi-axes, rotation) of the PCA box around `points` after outlier removal.

    Returns None when too few points remain or the shape is degenerate (a semi-axis below
    `params.min_axis`); callers count those, they never get NaN.
    """
    points = np.asarray(points, dtype=np.float64)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) > params.max_points:
        points = points[np.linspace(0, len(points) - 1, params.max_points).astype(int)]
    if len(points) < params.min_points:
        return None
    k = min(params.outlier_neighbors, len(points) - 1)
    distances, _ = cKDTree(points).query(points, k=k + 1)
    return _box(points, distances[:, 1:].mean(axis=1), params)


def fit_ellipsoid_depth(
    depth: np.ndarray, intrinsics: np.ndarray, mask: np.ndarray, params: FitParams = FitParams()
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """`fit_ellipsoid` of the valid depth pixels in `mask`, neighbours taken from the image.

    More than `params.max_points` pixels: every s-th row and column (s the smallest stride
    that fits), the image analogue of `fit_ellipsoid`'s even subsampling.
    """
    stride = max(1, math.ceil(math.sqrt(np.count_nonzero(mask) / params.max_points)))
    if stride > 1:
        depth, mask = depth[::stride, ::stride], mask[::stride, ::stride]
        intrinsics = intrinsics.copy()
        intrinsics[:2] /= stride
    radius = math.ceil((math.sqrt(params.outlier_neighbors + 1) - 1) / 2)  # a window holding k neighbours
    points, spread = _depth_points(params.outlier_neighbors, radius)(depth, mask, intrinsics.astype(np.float64))
    if len(points) < params.min_points:
        return None
    return _box(points, spread, params)


def _box(points: np.ndarray, spread: np.ndarray, params: FitParams) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The PCA box of the points whose neighbour distance `spread` is not an outlier: `_box_parts` in compiled
    code (LAPACK's `eigh` as numpy calls it), numpy's where the scatter is not finite (numba's `eigh` refuses it)."""
    parts = _box_parts(points, spread, params.outlier_std_ratio, params.min_points, params.min_axis)
    if parts[0] == Oriented.NOT_FINITE:
        limit, _, mean, scatter = _inliers(points, spread, params.outlier_std_ratio)
        _, eigenvectors = np.linalg.eigh(scatter)
        middle, axes = _extents_halved(points, spread, limit, mean, eigenvectors)
        parts = (*_oriented(axes, eigenvectors, params.min_axis), mean, middle, eigenvectors)
    return finished_box(*parts)


def finished_box(oriented: int, axes: np.ndarray, rotation: np.ndarray, mean: np.ndarray, middle: np.ndarray,
                 eigenvectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(center, semi-axes, rotation) from `_box_parts`: the centre added up by numpy's matrix product (BLAS's
    bits), the axes ordered by numpy's sort and determinant where `_oriented` was unsure; None for no box."""
    if oriented == Oriented.DEGENERATE:
        return None
    center = mean + eigenvectors @ middle
    if oriented == Oriented.UNSURE:  # numpy's sort and determinant decide, as they always have
        order = np.argsort(-axes)  # largest axis first, a stable convention for viewers and tests
        rotation = rotation[:, order]
        if np.linalg.det(rotation) < 0:
            rotation[:, 2] = -rotation[:, 2]
        axes = axes[order]
    return center, axes, rotation


@njit(cache=True)
def _box_parts(points: np.ndarray, spread: np.ndarray, ratio: float, min_points: int,
               min_axis: float) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_box` up to its centre, in one compiled call: (an `Oriented` value, `_oriented`'s axes and rotation, the
    inliers' mean, the middle of their extents and the scatter's eigenvectors). DEGENERATE also for fewer than
    `min_points` inliers, NOT_FINITE (and nothing else meaningful) for a scatter that is not finite. numba's
    `eigh` calls LAPACK's dsyevd as numpy's does: the same bits (tests/unit/perception/test_observations.py)."""
    limit, kept, mean, scatter = _inliers(points, spread, ratio)
    nothing = np.zeros(3)
    if kept < min_points:
        return Oriented.DEGENERATE.value, nothing, np.eye(3), mean, nothing, np.eye(3)
    if not np.isfinite(scatter).all():
        return Oriented.NOT_FINITE.value, nothing, np.eye(3), mean, nothing, np.eye(3)
    eigenvectors = np.ascontiguousarray(np.linalg.eigh(scatter)[1])  # C-ordered as numpy's: the same product
    middle, axes = _extents_halved(points, spread, limit, mean, eigenvectors)
    oriented, axes, rotation = _oriented(axes, eigenvectors, min_axis)
    return oriented, axes, rotation, mean, middle, eigenvectors


class Oriented(enum.IntEnum):
    """What `_oriented` made of a box's axes."""

    DONE = 0  # axes largest first, the rotation's columns in their order, right-handed
    DEGENERATE = 1  # an axis not finite or below the minimum: no ellipsoid
    UNSURE = 2  # two axes equal (numpy's sort orders ties its own way) or not a rotation: left as they were
    NOT_FINITE = 3  # (`_box_parts` only) a scatter that is not finite: numpy's `eigh` decides


@njit(cache=True)
def _oriented(axes: np.ndarray, rotation: np.ndarray, min_axis: float) -> tuple[int, np.ndarray, np.ndarray]:
    """(an `Oriented` value, the box's axes largest first, the rotation's columns in that order with its third
    negated where the determinant is negative): the sign of a determinant of +-1 from cofactors is LAPACK's."""
    if not (np.isfinite(axes).all() and np.isfinite(rotation).all()) or axes.min() < min_axis:
        return Oriented.DEGENERATE.value, axes, rotation
    a, b, c = axes[0], axes[1], axes[2]
    if a == b or b == c or a == c:
        return Oriented.UNSURE.value, axes, rotation
    if a > b:
        order = (0, 1, 2) if b > c else ((0, 2, 1) if a > c else (2, 0, 1))
    else:
        order = (1, 0, 2) if a > c else ((1, 2, 0) if b > c else (2, 1, 0))
    sorted_axes, turned = np.empty(3), np.empty((3, 3))
    for j in range(3):
        sorted_axes[j] = axes[order[j]]
        for i in range(3):
            turned[i, j] = rotation[i, order[j]]
    determinant = (turned[0, 0] * (turned[1, 1] * turned[2, 2] - turned[1, 2] * turned[2, 1])
                   - turned[0, 1] * (turned[1, 0] * turned[2, 2] - turned[1, 2] * turned[2, 0])
                   + turned[0, 2] * (turned[1, 0] * turned[2, 1] - turned[1, 1] * turned[2, 0]))
    if abs(determinant) < 0.5:
        return Oriented.UNSURE.value, axes, rotation
    if determinant < 0:
        for i in range(3):
            turned[i, 2] = -turned[i, 2]
    return Oriented.DONE.value, sorted_axes, turned


@njit(cache=True)
def _inliers(points: np.ndarray, spread: np.ndarray, ratio: float) -> tuple[float, int, np.ndarray, np.ndarray]:
    """(`_outlier_limit`, then `_inlier_moments` within it) in one call."""
    limit = _outlier_limit(spread, ratio)
    count, mean, scatter = _inlier_moments(points, spread, limit)
    return limit, count, mean, scatter


@njit(cache=True)
def _extents_halved(points: np.ndarray, spread: np.ndarray, limit: float, mean: np.ndarray,
                    rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The middle of `_extents` ((low + high) / 2) and half its size ((high - low) / 2), in one call."""
    low, high = _extents(points, spread, limit, mean, rotation)
    return (low + high) / 2, (high - low) / 2


@njit(cache=True)
def _outlier_limit(spread: np.ndarray, ratio: float) -> float:
    """Mean plus `ratio` standard deviations of the finite spreads (inf with none)."""
    count, total, square = 0, 0.0, 0.0
    for value in spread:
        if math.isfinite(value):
            count += 1
            total += value
    if count == 0:
        return np.inf
    mean = total / count
    for value in spread:
        if math.isfinite(value):
            square += (value - mean) ** 2
    return mean + ratio * math.sqrt(square / count)


@njit(cache=True)
def _inlier_moments(points: np.ndarray, spread: np.ndarray, limit: float) -> tuple[int, np.ndarray, np.ndarray]:
    """(count, mean, 3 x 3 scatter matrix) of the points whose spread is within `limit`, in one pass each,
    the sums in scalars (registers) and the scatter's lower triangle mirrored from the upper (equal bits)."""
    count, sum_x, sum_y, sum_z = 0, 0.0, 0.0, 0.0
    for i in range(len(points)):
        if spread[i] <= limit:
            count += 1
            sum_x += points[i, 0]
            sum_y += points[i, 1]
            sum_z += points[i, 2]
    mean, scatter = np.zeros(3), np.zeros((3, 3))
    if count == 0:
        return 0, mean, scatter
    mean[0], mean[1], mean[2] = sum_x / count, sum_y / count, sum_z / count
    xx, xy, xz, yy, yz, zz = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(len(points)):
        if spread[i] <= limit:
            dx, dy, dz = points[i, 0] - mean[0], points[i, 1] - mean[1], points[i, 2] - mean[2]
            xx += dx * dx
            xy += dx * dy
            xz += dx * dz
            yy += dy * dy
            yz += dy * dz
            zz += dz * dz
    scatter[0, 0], scatter[0, 1], scatter[0, 2] = xx, xy, xz
    scatter[1, 0], scatter[1, 1], scatter[1, 2] = xy, yy, yz
    scatter[2, 0], scatter[2, 1], scatter[2, 2] = xz, yz, zz
    return count, mean, scatter


@njit(cache=True)
def _extents(points: np.ndarray, spread: np.ndarray, limit: float, mean: np.ndarray,
             rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest coordinate of the inliers (spread within `limit`) along each principal axis
    (about `mean`), the three axes in one pass with the running bounds in scalars."""
    low_0, low_1, low_2, high_0, high_1, high_2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
    for i in range(len(points)):
        if spread[i] <= limit:
            dx, dy, dz = points[i, 0] - mean[0], points[i, 1] - mean[1], points[i, 2] - mean[2]
            along_0 = dx * rotation[0, 0] + dy * rotation[1, 0] + dz * rotation[2, 0]
            along_1 = dx * rotation[0, 1] + dy * rotation[1, 1] + dz * rotation[2, 1]
            along_2 = dx * rotation[0, 2] + dy * rotation[1, 2] + dz * rotation[2, 2]
            low_0, high_0 = min(low_0, along_0), max(high_0, along_0)
            low_1, high_1 = min(low_1, along_1), max(high_1, along_1)
            low_2, high_2 = min(low_2, along_2), max(high_2, along_2)
    return np.array([low_0, low_1, low_2]), np.array([high_0, high_1, high_2])


@functools.cache
def _depth_points(k: int, radius: int) -> Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The compiled pass `depth_points(depth, mask, intrinsics)` for `k` neighbours within `radius` pixels:
    `_neighbour_pass` with `k` and `radius` compiled in as constants (one cached compilation per pair; a closure
    over integers alone, so that numba's cache finds it again in the next process)."""

    @njit(cache=True)
    def depth_points(depth: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _neighbour_pass(depth, mask, intrinsics, k, radius)

    return depth_points


@njit(inline="always")
def _neighbour_pass(depth: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray, k: int,
                   radius: int) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) camera-frame points of the pixels of `mask` with a finite positive depth (row-major),
    and (P,) the mean 3D distance of each to its k nearest such pixels within `radius` pixels
    (fewer where fewer exist; inf for a pixel with none).

    Inlined where it is called, with `k` and `radius` constants there (`_depth_points`), so that the
    compiler unrolls and vectorizes by them. The pass runs one window offset at a time over a whole row
    of pixels, on flat arrays indexed by unsigned integers, so that the compiler vectorizes the loop over
    the row (README, Observation stage). The distance between two pixels is computed once, by the earlier
    of the two in row-major order for its `ahead` offsets (its own row's right, the rows below), and read
    back by the later one: (a - b)^2 and (b - a)^2 are the same bits, and each pixel still sums its
    neighbours' distances in window order.
    """
    side = 2 * radius + 1
    drop = max(side * side - 1 - k, 0)  # a pixel has at most side^2 - 1 neighbours; the farthest beyond k are dropped
    ahead = radius + radius * side  # the offsets after a pixel in window order
    rows = radius + 1  # the rows of distances kept: a pixel's own and the `radius` rows above it
    height, width = mask.shape
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    # coordinates on a flat grid padded by `radius` invalid pixels: every window lies inside it
    pitch = width + 2 * radius
    size = (height + 2 * radius) * pitch
    x, y, z, valid = np.zeros(size), np.zeros(size), np.zeros(size), np.zeros(size, np.bool_)
    first, last = np.full(height, width), np.full(height, -1)  # each row's valid columns, for the row pass
    count = 0
    for v in range(height):  # branch-free: an invalid pixel writes the zeros it had
        at = np.uint64((v + radius) * pitch + radius)
        row_first, row_last, row_count = width, -1, 0
        for u in range(width):
            depth_vu = depth[v, u]
            usable = mask[v, u] and depth_vu > 0 and depth_vu < np.inf  # finite and positive
            p = at + np.uint64(u)
            x[p] = (u - cx) * depth_vu / fx if usable else 0.0
            y[p] = (v - cy) * depth_vu / fy if usable else 0.0
            z[p] = depth_vu if usable else 0.0
            valid[p] = usable
            row_count += usable
            row_first = min(row_first, u if usable else width)
            row_last = u if usable else row_last
        count += row_count
        first[v], last[v] = row_first, row_last
    points = np.empty((count, 3))
    spread = np.full(count, np.inf)
    distances = np.zeros((ahead, rows * pitch))  # per ahead offset, the last `rows` rows' distances, by column
    total, near_count = np.empty(width), np.empty(width, np.int64)
    farthest = np.empty((max(drop, 1), width))  # per pixel, the largest distances so far, largest first
    plan = np.empty((side * side - 1, 3), np.int64)  # per neighbour: its row of distances, where, its pixel
    i = 0
    for v in range(height):
        if last[v] < 0:
            continue
        span = last[v] + 1 - first[v]
        start = np.uint64((v + radius) * pitch + radius + first[v])  # the row's first pixel in the grid
        own = (v % rows) * pitch + radius + first[v]  # ... and in the rows of distances
        for offset in range(ahead):  # this row's distances to the pixels ahead
            to_row = 0 if offset < radius else 1 + (offset - radius) // side
            to_column = offset + 1 if offset < radius else (offset - radius) % side - radius
            neighbour = np.uint64((v + radius + to_row) * pitch + radius + first[v] + to_column)
            out, at = distances[offset], np.uint64(own)
            for s in range(span):
                t = np.uint64(s)
                p, q = start + t, neighbour + t
                out[at + t] = math.sqrt((x[q] - x[p]) ** 2 + (y[q] - y[p]) ** 2 + (z[q] - z[p]) ** 2)
        for s in range(span):
            t = np.uint64(s)
            total[t], near_count[t] = 0.0, 0
            for j in range(drop):
                farthest[j, t] = -1.0
        listed = 0
        for to_row in range(-radius, radius + 1):  # every neighbour in window order
            for to_column in range(-radius, radius + 1):
                if to_row == 0 and to_column == 0:
                    continue  # not its own neighbour
                behind = to_row < 0 or (to_row == 0 and to_column < 0)  # its distance was computed there
                down, right = (-to_row, -to_column) if behind else (to_row, to_column)  # the offset ahead
                plan[listed, 0] = right - 1 if down == 0 else radius + (down - 1) * side + right + radius
                behind_at = ((v + to_row + rows) % rows) * pitch + radius + first[v] + to_column
                plan[listed, 1] = behind_at if behind else own
                plan[listed, 2] = (v + radius + to_row) * pitch + radius + first[v] + to_column
                listed += 1
        for group in range(0, listed, 4):  # four neighbours a pass over the row: side^2 - 1 is a multiple of 8
            four = plan[group:group + 4]
            row1, at1, near1 = distances[four[0, 0]], np.uint64(four[0, 1]), np.uint64(four[0, 2])
            row2, at2, near2 = distances[four[1, 0]], np.uint64(four[1, 1]), np.uint64(four[1, 2])
            row3, at3, near3 = distances[four[2, 0]], np.uint64(four[2, 1]), np.uint64(four[2, 2])
            row4, at4, near4 = distances[four[3, 0]], np.uint64(four[3, 1]), np.uint64(four[3, 2])
            for s in range(span):  # branch-free: an absent neighbour adds 0 and inserts -1
                t = np.uint64(s)
                in1, in2, in3, in4 = valid[near1 + t], valid[near2 + t], valid[near3 + t], valid[near4 + t]
                carry1 = row1[at1 + t] if in1 else -1.0
                carry2 = row2[at2 + t] if in2 else -1.0
                carry3 = row3[at3 + t] if in3 else -1.0
                carry4 = row4[at4 + t] if in4 else -1.0
                total[t] = ((((total[t] + (carry1 if in1 else 0.0)) + (carry2 if in2 else 0.0))
                             + (carry3 if in3 else 0.0)) + (carry4 if in4 else 0.0))  # in window order
                near_count[t] += in1 + in2 + in3 + in4
                for j in range(drop):  # insert the four into the sorted farthest list
                    kept = farthest[j, t]
                    larger = kept if kept > carry1 else carry1
                    carry1 = carry1 if kept > carry1 else kept
                    kept = larger if larger > carry2 else carry2
                    carry2 = carry2 if larger > carry2 else larger
                    larger = kept if kept > carry3 else carry3
                    carry3 = carry3 if kept > carry3 else kept
                    farthest[j, t] = larger if larger > carry4 else carry4
                    carry4 = carry4 if larger > carry4 else larger
        for s in range(span):
            p = start + np.uint64(s)
            if not valid[p]:
                continue
            n = near_count[s]
            points[i, 0], points[i, 1], points[i, 2] = x[p], y[p], z[p]
            kept = total[s]
            for j in range(n - k):  # the k nearest: the n - k farthest out, largest first
                kept -= farthest[j, s]
            if n:
                spread[i] = kept / min(n, k)
            i += 1
    return points, spread


def stack_ellipsoids(fits: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Ellipsoids:
    if not fits:
        return Ellipsoids.empty()
    centers, axes, rotations = zip(*fits)
    return Ellipsoids(np.array(centers), np.array(axes), np.array(rotations))


def backproject(depth: np.ndarray, intrinsics: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) camera-frame points of the valid depth pixels (inside `mask` when given)."""
    valid = np.isfinite(depth) & (depth > 0)
    if mask is not None:
        valid &= mask
    v, u = np.nonzero(valid)
    z = depth[v, u].astype(np.float64)
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    return np.column_stack(((u - cx) * z / fx, (v - cy) * z / fy, z))


def rotation_angle(rotation: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix, robust to round-off near 0 and pi."""
    cos = (np.trace(rotation) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_errors(estimate: Pose, truth: Pose) -> tuple[float, float]:
    """(translation error in metres, rotation error in radians) of camera-to-world poses."""
    te = float(np.linalg.norm(estimate.translation - truth.translation))
    re = rotation_angle(estimate.rotation.T @ truth.rotation)
    return te, re


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation drawn uniformly (QR of a Gaussian matrix, sign-fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> Pose:
    """Camera-to-world pose of a camera at `eye` looking at `target` (x right, y down, z forward)."""
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight along `up`
        right = np.cross(forward, np.array([1.0, 0.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return Pose(np.column_stack((right, down, forward)), np.asarray(eye, float).copy())
