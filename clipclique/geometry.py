"""Ellipsoid fits from point sets, rigid-transform helpers and pose errors.

The ellipsoid of an object is the one inscribed in its PCA oriented bounding box: centre = box
centre, semi-axes = half the box extents, rotation = the box's principal axes. open3d fits the
box; its tensor API is asked for PCA explicitly because its default is a different (minimal
volume) method.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clipclique.types import Ellipsoids, Pose


@dataclass(frozen=True)
class FitParams:
    """How a point set becomes an ellipsoid."""

    outlier_neighbors: int = 20  # statistical outlier removal: neighbours considered
    outlier_std_ratio: float = 2.0  # ... points farther than mean + ratio * std are cut
    min_points: int = 30  # fewer points than this: no ellipsoid
    min_axis: float = 0.01  # metres: a semi-axis shorter than this is degenerate (flat/line)
    max_points: int = 20_000  # larger sets are subsampled (evenly, deterministic) first


def fit_ellipsoid(points: np.ndarray, params: FitParams = FitParams()) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(center, semi-axes, rotation) of the PCA box around `points` after outlier removal.

    Returns None when too few points remain or the shape is degenerate (a semi-axis below
    `params.min_axis`); callers count those, they never get NaN.
    """
    import open3d as o3d

    points = np.asarray(points, dtype=np.float64)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) > params.max_points:
        points = points[np.linspace(0, len(points) - 1, params.max_points).astype(int)]
    if len(points) < params.min_points:
        return None
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud, _ = cloud.remove_statistical_outlier(params.outlier_neighbors, params.outlier_std_ratio)
    kept = np.asarray(cloud.points)
    if len(kept) < params.min_points:
        return None
    box = o3d.t.geometry.OrientedBoundingBox.create_from_points(
        o3d.core.Tensor(kept), robust=True, method=o3d.t.geometry.MethodOBBCreate.PCA
    )
    center = box.center.numpy().astype(np.float64)
    axes = box.extent.numpy().astype(np.float64) / 2.0
    rotation = box.rotation.numpy().astype(np.float64)
    if not (np.isfinite(axes).all() and np.isfinite(rotation).all()) or axes.min() < params.min_axis:
        return None
    order = np.argsort(-axes)  # largest axis first, a stable convention for viewers and tests
    rotation = rotation[:, order]
    if np.linalg.det(rotation) < 0:
        rotation[:, 2] = -rotation[:, 2]
    return center, axes[order], rotation


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
