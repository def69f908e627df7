"""Ground-truth alignment of a SLAM map: the demo_tum map moved by a known transform, with its
keyframe trajectory moved the same way, comes back within 1 mm and 0.01 degrees."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.datasets.tum import read_trajectory
from clipclique.interop.align import AlignmentLimits, align_trajectory, aligned_map
from clipclique.interop.errors import InteropError
from clipclique.mapping.build import build_map
from clipclique.pose.fit import Similarity
from clipclique.resolve import open_scene
from clipclique.types import Ellipsoids, Map, Pose

ROOT = Path(__file__).resolve().parents[2]
GROUNDTRUTH = ROOT / "data" / "demo" / "demo_tum" / "groundtruth.txt"
TRUE_ROTATION = Rotation.from_euler("zyx", [37, -12, 105], degrees=True).as_matrix()  # ground truth <- SLAM


@pytest.fixture(scope="module")
def demo_map() -> Map:
    map, _ = build_map(open_scene("demo_tum", ROOT / "data"), None)
    return map


def slam_files(tmp_path: Path, truth: Similarity, every: int = 25, noise_m: float = 0.0) -> Path:
    """A keyframe trajectory in the SLAM frame: the ground truth moved by the inverse of `truth`."""
    times, poses = read_trajectory(GROUNDTRUTH)
    rng = np.random.default_rng(0)
    lines = []
    for time, pose in list(zip(times, poses))[::every]:
        position = truth.pose.rotation.T @ (pose.translation - truth.pose.translation) / truth.scale
        position = position + rng.normal(0, noise_m, 3)
        quaternion = Rotation.from_matrix(truth.pose.rotation.T @ pose.rotation).as_quat()
        lines.append(f"{time + 0.004:.6f} " + " ".join(f"{v:.9f}" for v in (*position, *quaternion)))
    path = tmp_path / "keyframes_poses_desk_tum.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def moved(map: Map, truth: Similarity) -> Map:
    """The map as the SLAM system holds it: in its own frame (and scale)."""
    inverse = truth.pose.inverse()
    e = map.ellipsoids
    slam = Ellipsoids(inverse.apply(e.centers) / truth.scale, e.axes / truth.scale,
                      np.einsum("ij,njk->nik", inverse.rotation, e.rotations))
    return Map(slam, map.class_ids, map.class_names, map.descriptions, map.instance_ids)


def angle_deg(rotation: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(rotation) - 1) / 2, -1, 1)))


@pytest.mark.parametrize("scale", [1.0, 0.37])
def test_align_recovers_a_known_rigid_transform_and_similarity(tmp_path, demo_map, scale):
    truth = Similarity(scale, Pose(TRUE_ROTATION, np.array([1.5, -0.7, 0.3])))
    trajectory = slam_files(tmp_path, truth)
    alignment = align_trajectory(trajectory, GROUNDTRUTH, with_scale=scale != 1.0)
    assert alignment.matched == len(trajectory.read_text().splitlines()) >= 200
    assert alignment.rmse_m < 1e-3
    assert alignment.transform.scale == pytest.approx(scale, rel=1e-5)
    assert angle_deg(alignment.transform.pose.rotation.T @ TRUE_ROTATION) < 0.01
    assert np.abs(alignment.transform.pose.translation - truth.pose.translation).max() < 1e-3
    back = aligned_map(moved(demo_map, truth), alignment, "demo_tum", alignment.record(trajectory, GROUNDTRUTH))
    assert np.abs(back.ellipsoids.centers - demo_map.ellipsoids.centers).max() < 1e-3
    assert np.abs(back.ellipsoids.axes - demo_map.ellipsoids.axes).max() < 1e-3
    assert max(angle_deg(r.T @ s) for r, s in zip(back.ellipsoids.rotations, demo_map.ellipsoids.rotations)) < 0.01
    assert back.provenance["source"]["name"] == "demo_tum"
    assert back.provenance["alignment"]["matched_keyframes"] == alignment.matched


def test_a_monocular_map_fitted_rigidly_is_refused_with_the_rmse(tmp_path):
    trajectory = slam_files(tmp_path, Similarity(0.37, Pose(TRUE_ROTATION, np.zeros(3))))
    with pytest.raises(InteropError, match=r"keyframes_poses_desk_tum.txt: the keyframes fit .* cm RMSE over \d+ "
                                           r"keyframes, above the 5 cm allowed; a monocular map needs --scale"):
        align_trajectory(trajectory, GROUNDTRUTH)


def test_too_few_matched_keyframes_and_a_noisy_fit_are_refused_with_settable_limits(tmp_path):
    trajectory = slam_files(tmp_path, Similarity(1.0, Pose.identity()), every=700)
    with pytest.raises(InteropError, match=r"9 of 9 keyframes match a pose .* an alignment needs 10"):
        align_trajectory(trajectory, GROUNDTRUTH)
    assert align_trajectory(trajectory, GROUNDTRUTH, limits=AlignmentLimits(min_matched=9)).matched == 9
    noisy = slam_files(tmp_path, Similarity(1.0, Pose.identity()), noise_m=0.02)
    with pytest.raises(InteropError, match="above the 2 cm allowed"):
        align_trajectory(noisy, GROUNDTRUTH, limits=AlignmentLimits(max_rmse_m=0.02))
    assert align_trajectory(noisy, GROUNDTRUTH).rmse_m == pytest.approx(0.02 * math.sqrt(3), rel=0.15)


def test_an_aligned_import_is_taken_as_the_sequences_map(tmp_path, demo_map):
    """Exported, moved into a SLAM frame, imported with --align-to: back in place, and run as demo_tum's map."""
    from typer.testing import CliRunner

    from clipclique.interop.convert import landmarks_json
    from clipclique.io.mapfile import load_map
    from clipclique.localization.cli import app as loc_app
    from clipclique.mapping.cli import app as map_app

    runner = CliRunner()
    truth = Similarity(1.0, Pose(TRUE_ROTATION, np.array([1.5, -0.7, 0.3])))
    trajectory = slam_files(tmp_path, truth)
    document = json.loads(landmarks_json(demo_map))
    shifted = moved(demo_map, truth)
    for item, center, rotation in zip(document["landmarks"], shifted.ellipsoids.centers, shifted.ellipsoids.rotations):
        item["center"], item["rotation"] = center.tolist(), rotation.tolist()
    document["frame"] = "unknown"
    (tmp_path / "l.json").write_text(json.dumps(document))
    out = tmp_path / "aligned.map.npz"
    result = runner.invoke(map_app, ["import", str(tmp_path / "l.json"), "--align-to", "demo_tum", "--data-root",
                                     str(ROOT / "data"),
                                     "--trajectory", str(trajectory), "--encoder", "none", "--no-rrd", "--out",
                                     str(out)])
    assert result.exit_code == 0, result.output
    assert "aligned to demo_tum: 242 keyframes matched, RMSE 0.00 cm, scale 1.0000 (rigid)" in result.output
    aligned = load_map(out)
    assert np.abs(aligned.ellipsoids.centers - demo_map.ellipsoids.centers).max() < 1e-3
    assert aligned.provenance["alignment"]["matched_keyframes"] == 242
    ran = runner.invoke(loc_app, ["run", "demo_tum", "--data-root", str(ROOT / "data"), "--map", str(out), "--no-rrd",
                                  "--out", str(tmp_path / "run"), "--max-frames", "3", "-q"])
    assert ran.exit_code == 0, ran.output  # accepted as demo_tum's map without --same-place
