"""clipclique-loc run --window: fused windows through the runner, its outputs and its refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from clipclique.backends import load_encoder
from clipclique.datasets.tum import tum_line
from clipclique.io.mapfile import save_map
from clipclique.localization.cli import app
from clipclique.localization.run import RunSettings, run_and_save
from clipclique.mapping.build import build_map
from clipclique.resolve import open_scene

ROOT = Path(__file__).resolve().parents[2]
SCENE = "demo_apartment"  # ground-truth instances: quick to observe


@pytest.fixture(scope="module")
def map_path(tmp_path_factory) -> Path:
    map, _ = build_map(open_scene(SCENE, ROOT / "data"), load_encoder("simulated"))
    path = tmp_path_factory.mktemp("maps") / f"{SCENE}.map.npz"
    save_map(map, path)
    return path


def settings(map_path: Path, out: Path, **window) -> RunSettings:
    return RunSettings(SCENE, map_path=map_path, data_root=ROOT / "data", max_frames=6, out=out, **window)


def test_simulated_odometry_windows_are_recorded_per_frame(map_path, tmp_path):
    document = run_and_save(settings(map_path, tmp_path / "w", window=3, odometry="groundtruth", odometry_drift=1.0))
    window = document["run"]["window"]
    assert window["size"] == 3 and window["odometry"]["simulated"] and "simulated" in window["odometry"]["name"]
    assert [frame["window"]["frames"] for frame in document["frames"]] == [[0], [0, 1], [0, 1, 2], [1, 2, 3],
                                                                           [2, 3, 4], [3, 4, 5]]
    assert document["summary"]["window_frames_without_odometry"] == 0
    single = run_and_save(settings(map_path, tmp_path / "one"))
    assert "window" not in single["run"] and "window" not in single["frames"][0]
    # a fused window holds more objects than its newest frame, only the newest frame's have boxes
    assert any(f["observations"] > s["observations"] for f, s in zip(document["frames"], single["frames"]))
    assert all(f["window"]["observations_with_box"] == s["observations"]
               for f, s in zip(document["frames"], single["frames"]))
    assert document["frames"][0]["hypotheses"] == single["frames"][0]["hypotheses"]  # a window of one is the frame
    assert (tmp_path / "w" / "recording.rrd").stat().st_size > 0


def test_a_window_span_spreads_the_k_frames_over_that_many_seconds(map_path, tmp_path):
    timestamps, _ = open_scene(SCENE, ROOT / "data").trajectory()
    interval = float(np.median(np.diff(timestamps)))
    span = 4 * interval  # K = 3 frames, every other one
    document = run_and_save(settings(map_path, tmp_path / "w", window=3, window_span=span, odometry="groundtruth"))
    assert document["run"]["window"]["step"] == 2 and document["run"]["window"]["span_s"] == span
    assert [frame["window"]["frames"] for frame in document["frames"]] == [[0], [1], [0, 2], [1, 3], [0, 2, 4],
                                                                           [1, 3, 5]]
    assert f"window_span={span}" in document["run"]["name"] and "window_step" not in document["run"]["name"]
    plain = run_and_save(settings(map_path, tmp_path / "k", window=3, odometry="groundtruth"))
    assert plain["run"]["window"]["step"] == 1 and plain["run"]["window"]["span_s"] is None  # --window K alone


def test_a_trajectory_file_matched_by_time_and_frames_without_odometry_counted(map_path, tmp_path):
    timestamps, truth = open_scene(SCENE, ROOT / "data").trajectory()
    lines = [tum_line(t, pose) for i, (t, pose) in enumerate(zip(timestamps, truth)) if i != 2]
    (tmp_path / "vo.tum").write_text("\n".join(lines) + "\n")
    document = run_and_save(settings(map_path, tmp_path / "w", window=3, odometry=str(tmp_path / "vo.tum")))
    assert document["run"]["window"]["odometry"] == {"name": "vo.tum", "simulated": False, "drift_percent": None}
    frames = [frame["window"] for frame in document["frames"]]
    assert [f["frames"] for f in frames] == [[0], [0, 1], [2], [1, 3], [3, 4], [3, 4, 5]]
    assert [f["without_odometry"] for f in frames] == [0, 0, 2, 1, 1, 0]
    assert document["summary"]["window_frames_without_odometry"] == 4


@pytest.mark.parametrize(("arguments", "message"), [
    (["--window", "3"], "--window 3 needs --odometry"),
    (["--odometry", "groundtruth"], "need --window K"),
    (["--window", "3", "--odometry", "vo.tum", "--odometry-drift", "1"], "simulates drift on ground truth"),
    (["--window", "3", "--odometry", "missing.tum"], "missing.tum"),
    (["--window", "3", "--window-span", "2", "--window-step", "1", "--odometry", "groundtruth"],
     "--window-span 2 and --window-step 1 are mutually exclusive"),
    (["--window", "3", "--window-span", "2", "--window-step", "4", "--odometry", "groundtruth"],
     "mutually exclusive: give the span (seconds) or the step (frames)"),
    (["--window-span", "2"], "--window-span 2 needs --window K"),
    (["--window", "3", "--window-span", "0", "--odometry", "groundtruth"], "expected a positive number of seconds"),
    (["--window", "3", "--window-span", "nan", "--odometry", "groundtruth"], "expected a positive number of seconds"),
])
def test_window_refusals_are_one_line(map_path, tmp_path, arguments, message):
    (tmp_path / "vo.tum").write_text("0 0 0 0 0 0 0 1\n")
    result = CliRunner().invoke(app, ["run", SCENE, "--data-root", str(ROOT / "data"), "--map", str(map_path),
                                      "--out", str(tmp_path / "out"), *[a.replace("vo.tum", str(tmp_path / "vo.tum"))
                                                                         for a in arguments]])
    assert result.exit_code == 2 and message in result.output, result.output
    assert not (tmp_path / "out").exists()
