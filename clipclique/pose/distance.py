"""How far one camera pose is from another: the translation and rotation errors scored against ground truth."""

from __future__ import annotations

import numpy as np

from clipclique.types import Pose


def rotation_angle(rotation: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix, robust to round-off near 0 and pi."""
    cos = (np.trace(rotation) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_errors(estimate: Pose, truth: Pose) -> tuple[float, float]:
    """(translation error in metres, rotation error in radians) of camera-to-world poses."""
    te = float(np.linalg.norm(estimate.translation - truth.translation))
    re = rotation_angle(estimate.rotation.T @ truth.rotation)
    return te, re
