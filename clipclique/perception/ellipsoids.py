"""Ellipsoid fits from point sets: the ellipsoid inscribed in the points' PCA oriented bounding box.

Centre = box centre, semi-axes = half the box extents, rotation = the principal axes of the points (the
eigenvectors of their covariance). Statistical outlier removal first cuts points whose mean
distance to their `outlier_neighbors` nearest neighbours exceeds the cloud's mean of that by
`outlier_std_ratio` standard deviations. For a free point set (the map builder's fused
instances) the neighbours come from a KD-tree; for one view's depth pixels
(`fit_ellipsoid_depth`) from the pixel's image window (clipclique.perception.depth), in compiled
code: about 30x faster than the KD-tree search open3d used (README, Benchmarks).
"""

from __future__ import annotations

import enum
import math

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from clipclique.config import FitParams
from clipclique.perception.depth import _depth_points
from clipclique.types import Ellipsoids


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
        middle, axes = _middle_and_half_size(points, spread, limit, mean, eigenvectors)
        parts = (*_orientation(axes, eigenvectors, params.min_axis), mean, middle, eigenvectors)
    return finished_box(*parts)


def finished_box(oriented: int, axes: np.ndarray, rotation: np.ndarray, mean: np.ndarray, middle: np.ndarray,
                 eigenvectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(center, semi-axes, rotation) from `_box_parts`: the centre added up by numpy's matrix product (BLAS's
    bits), the axes ordered by numpy's sort and determinant where `_orientation` was unsure; None for no box."""
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
    """`_box` up to its centre, in one compiled call: (an `Oriented` value, `_orientation`'s axes and rotation, the
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
    middle, axes = _middle_and_half_size(points, spread, limit, mean, eigenvectors)
    oriented, axes, rotation = _orientation(axes, eigenvectors, min_axis)
    return oriented, axes, rotation, mean, middle, eigenvectors


class Oriented(enum.IntEnum):
    """What `_orientation` made of a box's axes."""

    DONE = 0  # axes largest first, the rotation's columns in their order, right-handed
    DEGENERATE = 1  # an axis not finite or below the minimum: no ellipsoid
    UNSURE = 2  # two axes equal (numpy's sort orders ties its own way) or not a rotation: left as they were
    NOT_FINITE = 3  # (`_box_parts` only) a scatter that is not finite: numpy's `eigh` decides


@njit(cache=True)
def _orientation(axes: np.ndarray, rotation: np.ndarray, min_axis: float) -> tuple[int, np.ndarray, np.ndarray]:
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
def _middle_and_half_size(points: np.ndarray, spread: np.ndarray, limit: float, mean: np.ndarray,
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


def stack_ellipsoids(fits: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Ellipsoids:
    if not fits:
        return Ellipsoids.empty()
    centers, axes, rotations = zip(*fits)
    return Ellipsoids(np.array(centers), np.array(axes), np.array(rotations))
