"""Odometry for window localization: where each frame's camera was, in some drifting world of its own.

Only relative motion within a short window is used, so the odometry's world frame is arbitrary.
Three sources:
- a metric trajectory file in TUM format (`timestamp tx ty tz qx qy qz qw`, camera-to-world) from a
  VO or SLAM system, matched to the frames by timestamp (nearest within `MAX_TIME_DIFF`, as TUM's
  associate.py; a frame without a match has no odometry). Scale-free monocular odometry is out of
  scope: its translations would be in an unknown unit, and the fused window would be wrong.
- ground truth with a simulated drift (`drifting`), named "simulated" in every output. The drift
  model, seeded: between consecutive frames with ground truth, the true relative motion (distance
  d, rotation angle theta) gets a translation error of length PCT % of d and a rotation error of
  PCT % of theta. Each error points along a direction that itself random-walks slowly (a unit
  vector nudged by N(0, DIRECTION_WANDER^2) per step and re-normalized), so that over a window the
  errors add up nearly in line: the odometry is off by about PCT % of the distance travelled and of
  the angle turned (the relative error of KITTI's odometry benchmark), the worst case for its
  percentage. A frame without ground truth has no odometry.
- a ROS bag's own (`bag_odometry`): `tf:PARENT:CHILD` (the camera's pose from /tf, static transforms applied)
  or `topic:/odom` (a nav_msgs/Odometry topic, matched by stamp as a trajectory file is).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from clipclique.datasets import Sequence
from clipclique.datasets.rosbag import BagSequence
from clipclique.datasets.tum import MAX_TIME_DIFF, associate, read_trajectory
from clipclique.errors import ClipcliqueError, DatasetError
from clipclique.pose.distance import rotation_angle
from clipclique.types import Pose

GROUND_TRUTH = "groundtruth"  # the source name of ground truth with simulated drift
BAG_SOURCES = ("tf:", "topic:")  # a bag's odometry: tf:PARENT:CHILD, topic:/odom
DIRECTION_WANDER = 0.1  # per step: how fast the drift's direction turns (radians, roughly)


@dataclass
class Odometry:
    """Camera-to-odometry-world pose per frame (None: no odometry for that frame)."""

    poses: list[Pose | None]
    name: str  # what it is, for outputs: "trajectory.tum", "ground truth + 1% drift (simulated)"
    simulated: bool


def open_odometry(source: str, drift_percent: float, seed: int, timestamps: np.ndarray,
                  truth: list[Pose | None], sequence: Sequence | None = None) -> Odometry:
    """`source` GROUND_TRUTH (with the simulated drift), a TUM trajectory file, or (`sequence` a bag) a
    `BAG_SOURCES` source, for frames at `timestamps`."""
    if source == GROUND_TRUTH:
        return drifting(truth, drift_percent, seed)
    if drift_percent:
        raise ClipcliqueError(f"--odometry-drift simulates drift on ground truth (--odometry {GROUND_TRUTH}), "
                              f"not on {source}")
    if source.startswith(BAG_SOURCES):
        return bag_odometry(source, sequence)
    return from_trajectory(Path(source), timestamps)


def from_trajectory(path: Path, timestamps: np.ndarray, max_diff: float = MAX_TIME_DIFF) -> Odometry:
    """The poses of a TUM trajectory file nearest in time to each frame's timestamp (DatasetError on a bad
    file or one that matches no frame)."""
    path = Path(path)
    times, poses = read_trajectory(path)
    return nearest_odometry(times, poses, timestamps, str(path), path.name, max_diff)


def nearest_odometry(times: np.ndarray, poses: list[Pose], timestamps: np.ndarray, where: str, name: str,
                     max_diff: float = MAX_TIME_DIFF) -> Odometry:
    """The poses at `times` nearest to each frame's timestamp; a DatasetError naming `where` when none is near."""
    nearest = associate(np.asarray(timestamps, np.float64), np.asarray(times, np.float64), max_diff)
    if len(timestamps) and (nearest < 0).all():
        raise DatasetError(f"{where}: no pose within {max_diff} s of any frame's timestamp (frames at "
                           f"{timestamps[0]:.3f} .. {timestamps[-1]:.3f} s)")
    return Odometry([poses[k] if k >= 0 else None for k in nearest], name, simulated=False)


def bag_odometry(source: str, sequence: Sequence | None) -> Odometry:
    """`tf:PARENT:CHILD` or `topic:/odom` of the bag `sequence` (a ClipcliqueError when it is no bag)."""
    if not isinstance(sequence, BagSequence):
        raise ClipcliqueError(f"--odometry {source}: tf: and topic: read a ROS bag's messages; this sequence is not a "
                              "bag (give FILE.tum or groundtruth)")
    kind, _, rest = source.partition(":")
    if kind == "tf":
        poses = sequence.tf_poses(rest, "--odometry tf:")
        if not any(pose is not None for pose in poses):
            raise DatasetError(f"{sequence.root}: --odometry {source}: /tf has no transform within "
                               f"{MAX_TIME_DIFF} s of any frame")
        return Odometry(poses, source, simulated=False)
    times, poses = sequence.odometry_track(rest)
    return nearest_odometry(times, poses, sequence.timestamps, f"{sequence.root}, {rest}", source)


def drifting(truth: list[Pose | None], percent: float, seed: int = 0) -> Odometry:
    """Ground-truth poses with the module's drift model of `percent` % (0: exact), seeded."""
    rng = np.random.default_rng(seed)
    drift_t, drift_r = _unit(rng.normal(size=3)), _unit(rng.normal(size=3))
    poses: list[Pose | None] = []
    previous_truth = previous = None
    for pose in truth:
        if pose is None:
            poses.append(None)
            continue
        if previous is None or percent == 0:
            current = pose
        else:
            step = previous_truth.inverse().compose(pose)  # the true motion, in the previous camera's frame
            drift_t = _unit(drift_t + rng.normal(scale=DIRECTION_WANDER, size=3))
            drift_r = _unit(drift_r + rng.normal(scale=DIRECTION_WANDER, size=3))
            fraction = percent / 100.0
            error = Rotation.from_rotvec(fraction * rotation_angle(step.rotation) * drift_r).as_matrix()
            noisy = Pose(error @ step.rotation,
                         step.translation + fraction * float(np.linalg.norm(step.translation)) * drift_t)
            current = previous.compose(noisy)
        poses.append(current)
        previous_truth, previous = pose, current
    name = "ground truth" + (f" + {percent:g}% drift" if percent else "") + " (simulated)"
    return Odometry(poses, name, simulated=True)


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / max(float(np.linalg.norm(vector)), 1e-12)
