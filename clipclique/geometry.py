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

import functools
import math
from collections.abc import Callable

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from clipclique.config import FitParams
from clipclique.types import Ellipsoids, Pose


def fit_ellipsoid(points: np.ndarray, params: FitParams = FitParams()) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
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
    """The PCA box of the points whose neighbour distance `spread` is not an outlier."""
    kept, mean, scatter = _inlier_moments(points, spread, params.outlier_std_ratio)
    if kept < params.min_points:
        return None
    _, rotation = np.linalg.eigh(scatter)
    low, high = _extents(points, spread, mean, rotation, params.outlier_std_ratio)
    center = mean + rotation @ ((low + high) / 2)
    axes = (high - low) / 2
    if not (np.isfinite(axes).all() and np.isfinite(rotation).all()) or axes.min() < params.min_axis:
        return None
    order = np.argsort(-axes)  # largest axis first, a stable convention for viewers and tests
    rotation = rotation[:, order]
    if np.linalg.det(rotation) < 0:
        rotation[:, 2] = -rotation[:, 2]
    return center, axes[order], rotation


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
def _inlier_moments(points: np.ndarray, spread: np.ndarray, ratio: float) -> tuple[int, np.ndarray, np.ndarray]:
    """(count, mean, 3 x 3 scatter matrix) of the points within the outlier limit, in one pass each."""
    limit = _outlier_limit(spread, ratio)
    count, mean, scatter = 0, np.zeros(3), np.zeros((3, 3))
    for i in range(len(points)):  # element by element: row slices would allocate in the loop
        if spread[i] <= limit:
            count += 1
            for r in range(3):
                mean[r] += points[i, r]
    if count == 0:
        return 0, mean, scatter
    mean /= count
    for i in range(len(points)):
        if spread[i] <= limit:
            for r in range(3):
                for c in range(3):
                    scatter[r, c] += (points[i, r] - mean[r]) * (points[i, c] - mean[c])
    return count, mean, scatter


@njit(cache=True)
def _extents(points: np.ndarray, spread: np.ndarray, mean: np.ndarray, rotation: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest coordinate of the inliers along each principal axis (about `mean`)."""
    limit = _outlier_limit(spread, ratio)
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    for i in range(len(points)):
        if spread[i] <= limit:
            for axis in range(3):
                value = ((points[i, 0] - mean[0]) * rotation[0, axis] + (points[i, 1] - mean[1]) * rotation[1, axis]
                         + (points[i, 2] - mean[2]) * rotation[2, axis])
                low[axis] = min(low[axis], value)
                high[axis] = max(high[axis], value)
    return low, high


@functools.cache
def _depth_points(k: int, radius: int) -> Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The compiled pass `depth_points(depth, mask, intrinsics)` for `k` neighbours within `radius` pixels.

    `k` and `radius` are compiled in as constants (one cached compilation per pair), so the
    insertion into the list of distances to drop unrolls, without a branch; the pass runs one
    window offset at a time over a whole row of pixels (README, Observation stage).
    """
    side = 2 * radius + 1
    drop = max(side * side - 1 - k, 0)  # a pixel has at most side^2 - 1 neighbours; the farthest beyond k are dropped

    @njit(cache=True)
    def depth_points(depth: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P, 3) camera-frame points of the pixels of `mask` with a finite positive depth (row-major),
        and (P,) the mean 3D distance of each to its k nearest such pixels within `radius` pixels
        (fewer where fewer exist; inf for a pixel with none)."""
        height, width = mask.shape
        fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
        # coordinates on a grid padded by `radius` invalid pixels: every window lies inside it
        shape = (height + 2 * radius, width + 2 * radius)
        x, y, z, valid = np.zeros(shape), np.zeros(shape), np.zeros(shape), np.zeros(shape, np.bool_)
        first, last = np.full(height, width), np.full(height, -1)  # each row's valid columns, for the row pass
        count = 0
        for v in range(height):
            for u in range(width):
                depth_vu = depth[v, u]
                if mask[v, u] and math.isfinite(depth_vu) and depth_vu > 0:
                    a, b = v + radius, u + radius
                    x[a, b], y[a, b], z[a, b] = (u - cx) * depth_vu / fx, (v - cy) * depth_vu / fy, depth_vu
                    valid[a, b] = True
                    count += 1
                    first[v], last[v] = min(first[v], u), u
        points = np.empty((count, 3))
        spread = np.full(count, np.inf)
        # one row at a time, each window offset over the row's span: the loop over columns has no branch;
        # per pixel the sum and the sorted list see the offsets in window order, as a pixel-by-pixel pass does
        total, near_count = np.empty(width), np.empty(width, np.int64)
        farthest = np.empty((max(drop, 1), width))  # per pixel, the largest distances so far, largest first
        i = 0
        for v in range(height):
            if last[v] < 0:
                continue
            a, lo, hi = v + radius, first[v] + radius, last[v] + radius + 1
            total[:], near_count[:], farthest[:] = 0.0, 0, -1.0
            for aa in range(a - radius, a + radius + 1):
                for offset in range(-radius, radius + 1):
                    if aa == a and offset == 0:
                        continue  # not its own neighbour
                    span = slice(lo + offset, hi + offset)  # the neighbours at this offset, as contiguous rows
                    xs, ys, zs, vs = x[aa, span], y[aa, span], z[aa, span], valid[aa, span]
                    xa, ya, za = x[a, lo:hi], y[a, lo:hi], z[a, lo:hi]
                    tot, cnt = total[lo - radius:hi - radius], near_count[lo - radius:hi - radius]
                    far = farthest[:, lo - radius:hi - radius]
                    for t in range(hi - lo):  # branch-free: an absent neighbour adds 0
                        near = vs[t]
                        distance = math.sqrt((xs[t] - xa[t]) ** 2 + (ys[t] - ya[t]) ** 2 + (zs[t] - za[t]) ** 2)
                        tot[t] += distance if near else 0.0
                        cnt[t] += near
                        carry = distance if near else -1.0
                        for j in range(drop):  # insert into the sorted farthest list
                            kept = far[j, t]
                            far[j, t] = kept if kept > carry else carry
                            carry = carry if kept > carry else kept
            for b in range(lo, hi):
                if not valid[a, b]:
                    continue
                u, n = b - radius, near_count[b - radius]
                points[i, 0], points[i, 1], points[i, 2] = x[a, b], y[a, b], z[a, b]
                kept = total[u]
                for j in range(n - k):  # the k nearest: the n - k farthest out, largest first
                    kept -= farthest[j, u]
                if n:
                    spread[i] = kept / min(n, k)
                i += 1
        return points, spread

    return depth_points


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
