"""Odometry sources of window localization: a TUM trajectory matched by time, ground truth with drift."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.errors import DatasetError
from clipclique.multiframe.odometry import drifting, from_trajectory
from clipclique.pose.distance import rotation_angle
from clipclique.types import Pose


def walk(steps: int = 100, length: float = 10.0, turn_deg: float = 90.0) -> list[Pose]:
    """A camera moving along x while turning about z at an even rate."""
    angles = np.radians(np.linspace(0.0, turn_deg, steps + 1))
    return [Pose(Rotation.from_euler("z", a).as_matrix(), np.array([x, 0.0, 0.0]))
            for a, x in zip(angles, np.linspace(0.0, length, steps + 1))]


def relative(a: Pose, b: Pose) -> Pose:
    return a.inverse().compose(b)


def test_no_drift_is_the_ground_truth_and_frames_without_it_have_none():
    truth = walk(10)
    truth[4] = None
    odometry = drifting(truth, 0.0)
    assert odometry.poses[4] is None and odometry.simulated and "simulated" in odometry.name
    assert all(p is q for p, q in zip(odometry.poses, truth))


@pytest.mark.parametrize("percent", [1.0, 3.0])
def test_drift_over_a_window_is_about_the_percentage_of_the_motion(percent):
    truth = walk()
    odometry = drifting(truth, percent, seed=5).poses
    translation, rotation = [], []
    for start in range(0, 90, 10):  # windows of 10 steps: 1 m and 9 degrees
        true, seen = relative(truth[start], truth[start + 10]), relative(odometry[start], odometry[start + 10])
        translation.append(np.linalg.norm(seen.translation - true.translation) / np.linalg.norm(true.translation))
        rotation.append(rotation_angle(seen.rotation.T @ true.rotation) / rotation_angle(true.rotation))
    assert 0.85 * percent / 100 < np.median(translation) <= 1.1 * percent / 100  # rotation drift adds a little
    assert 0.85 * percent / 100 < np.median(rotation) <= 1.01 * percent / 100


def test_drift_is_seeded():
    truth = walk(20)
    same = [drifting(truth, 1.0, seed=2).poses[-1].translation for _ in range(2)]
    np.testing.assert_array_equal(*same)
    assert not np.array_equal(same[0], drifting(truth, 1.0, seed=3).poses[-1].translation)


def test_trajectory_matched_by_timestamp(tmp_path):
    path = tmp_path / "vo.tum"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n1.000 1 2 3 0 0 0 1\n2.005 4 5 6 0 0 0 1\n")
    odometry = from_trajectory(path, np.array([1.01, 1.5, 2.0]))
    assert not odometry.simulated and odometry.name == "vo.tum"
    assert odometry.poses[1] is None
    np.testing.assert_array_equal(odometry.poses[0].translation, [1, 2, 3])
    np.testing.assert_array_equal(odometry.poses[2].translation, [4, 5, 6])


def test_a_bad_trajectory_line_names_the_file_and_line(tmp_path):
    path = tmp_path / "vo.tum"
    path.write_text("1.0 1 2 3 0 0 0 1\n2.0 4 5 6 0 0 0\n")
    with pytest.raises(DatasetError, match=r"vo.tum, line 2"):
        from_trajectory(path, np.array([1.0]))
