"""Ellipsoids as dual quadrics, the way OA-SLAM, VOOM and GOReloc store them.

An ellipsoid (centre c, rotation R with the axis directions as columns, semi-axes a, b, c_) is
`Q* = T diag(a^2, b^2, c_^2, -1) T^T` with `T = [[R, c], [0, 1]]`, scaled so that `Q*[3, 3] = -1`.
"""

from __future__ import annotations

import numpy as np

from clipclique.interop.errors import InteropError

SYMMETRY_TOLERANCE = 1e-5  # |Q* - Q*^T| allowed, relative to the largest entry: float32 storage round-off


def encode_dual_quadric(center: np.ndarray, axes: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(4, 4) Q* of one ellipsoid, normalised to Q*[3, 3] = -1."""
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = center
    return transform @ np.diag([*np.square(axes), -1.0]) @ transform.T


def decode_dual_quadric(quadric: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, semi-axes, rotation with det +1) of a dual quadric; InteropError naming `where` when
    it is not a symmetric dual quadric of a real ellipsoid."""
    q = np.asarray(quadric, dtype=np.float64).reshape(4, 4)
    if not np.isfinite(q).all():
        raise InteropError(f"{where}: the dual quadric holds non-finite numbers")
    scale = float(np.max(np.abs(q)))
    asymmetry = float(np.max(np.abs(q - q.T)))
    if asymmetry > SYMMETRY_TOLERANCE * max(scale, 1.0):
        raise InteropError(f"{where}: the dual quadric is not symmetric (|Q - Q^T| up to {asymmetry:.3g}); "
                           "not an ellipsoid")
    if q[3, 3] >= -1e-12 * max(scale, 1.0):
        raise InteropError(f"{where}: the dual quadric has Q[3,3] = {q[3, 3]:.3g}, not negative; not an ellipsoid")
    q = (q + q.T) / 2 / -q[3, 3]
    center = -q[:3, 3]
    shape = q[:3, :3] + np.outer(center, center)
    squares, rotation = np.linalg.eigh(shape)
    if squares.min() <= 0:
        raise InteropError(f"{where}: the dual quadric is not an ellipsoid (a squared semi-axis of "
                           f"{squares.min():.3g})")
    if np.linalg.det(rotation) < 0:
        rotation[:, 2] *= -1
    return center, np.sqrt(squares), rotation
