"""`clipclique-loc run BAG`: a demo_tum folder written as bags localizes as the folder does.

A bag has no instance images, which the simulated detector and CLIP read, so like is compared with like:
the folder's simulated detections saved as a detection file (`--detector file:`) and `--encoder none`, on
the folder and on its bags. The ROS 1 bag and the mcap (rgb8, 32FC1) decide every frame as the folder
(tests/tolerance.py with no frame differing); the RealSense-style bag (JPEG colour, millimetre depth) has the
folder's success within two frames at every threshold.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from tolerance import compare, decisions
from typer.testing import CliRunner

from clipclique.backends import load_encoder
from clipclique.datasets import BagOptions
from clipclique.io.mapfile import save_map
from clipclique.localization.cli import app
from clipclique.localization.results import read_results
from clipclique.localization.run import RunSettings, run_and_save
from clipclique.mapping.build import build_map
from clipclique.resolve import open_scene

RUNNER = CliRunner()


@pytest.fixture(scope="module")
def recording(demo_data, bag_tools, tmp_path_factory) -> dict[str, Path]:
    """The folder, its map, its detections and its three bags."""
    root = tmp_path_factory.mktemp("bag-run")
    folder = demo_data("demo_tum", frames=8) / "demo" / "demo_tum"
    map, _ = build_map(open_scene(str(folder)), load_encoder("simulated"))
    save_map(map, root / "demo_tum.map.npz")
    found = {
        "folder": folder,
        "map": root / "demo_tum.map.npz",
        "detections": bag_tools.write_detections(folder, root / "demo_tum.map.npz", root / "det" / "detections.json"),
    }
    for name, storage, layout in (
        ("ros1", "ros1", "tum"),
        ("mcap", "mcap", "tum"),
        ("realsense", "sqlite3", "realsense"),
    ):
        found[name] = bag_tools.write_bag(
            folder, root / name / ("demo_tum.bag" if storage == "ros1" else "demo_tum"), storage, layout
        )
    found["frames"] = {layout: bag_tools.LAYOUTS[layout]["frame"] for layout in bag_tools.LAYOUTS}
    return found


def localized(recording: dict[str, Path], sequence: Path, out: Path, bag: BagOptions | None = None, progress=None,
              **given) -> dict:
    settings = RunSettings(
        str(sequence),
        map_path=recording["map"],
        detector=f"file:{recording['detections']}",
        encoder="none",
        out=out,
        record=False,
        bag=bag,
        **given,
    )
    run_and_save(settings, progress)
    return read_results(out / "results.json")


@pytest.fixture(scope="module")
def folder_run(recording, tmp_path_factory) -> dict:
    reached = []
    document = localized(recording, recording["folder"], tmp_path_factory.mktemp("folder-run"), progress=reached.append)
    assert [(step.done, step.total, step.bag_time) for step in reached] == [(i, 8, None) for i in range(1, 9)]
    return document


def test_a_bag_run_reports_its_progress_in_bag_time(recording, tmp_path):
    """The progress of a bag is its time since the first frame selected, of the selection's span (frames
    seconds apart in demo_tum's walk); a folder's counts frames only (folder_run)."""
    reached = []
    localized(recording, recording["ros1"], tmp_path, progress=reached.append, stride=2)
    stamps, _ = open_scene(str(recording["ros1"])).trajectory()
    span = stamps[6] - stamps[0]
    assert span > 30  # the walk's frames are seconds apart
    assert [step.done for step in reached] == [1, 2, 3, 4] and {step.total for step in reached} == {4}
    assert [step.bag_time[0] for step in reached] == pytest.approx([stamps[i] - stamps[0] for i in (0, 2, 4, 6)])
    assert [step.bag_time[1] for step in reached] == pytest.approx([span] * 4)
    assert reached[-1].describe() == f"bag time {span:.1f} / {span:.1f} s"


@pytest.mark.parametrize("bag", ["ros1", "mcap"])
def test_an_rgb8_32fc1_bag_decides_as_its_folder(recording, folder_run, tmp_path, bag):
    document = localized(
        recording, recording[bag], tmp_path, BagOptions(gt_frames=f"world:{recording['frames']['tum']}")
    )
    expected = decisions(folder_run)
    assert sum(bool(frame["hypotheses"]) for frame in expected) >= 1  # not a comparison of failures alone
    comparison = compare(expected, decisions(document))
    assert comparison.frames == 8 and comparison.differing == {}, comparison.report()
    assert document["summary"]["success@1"] == folder_run["summary"]["success@1"]


def test_a_realsense_bag_succeeds_within_two_frames(recording, folder_run, tmp_path):
    groundtruth = recording["folder"] / "groundtruth.txt"
    document = localized(recording, recording["realsense"], tmp_path, BagOptions(groundtruth=groundtruth))
    comparison = compare(decisions(folder_run), decisions(document))
    assert all(abs(expected - found) <= 2 for expected, found in comparison.success.values()), comparison.report()


def test_the_cli_names_its_folder_after_the_bag_and_says_no_ground_truth(recording, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = RUNNER.invoke(
        app,
        [
            "run",
            str(recording["ros1"]),
            "--map",
            str(recording["map"]),
            "--detector",
            f"file:{recording['detections']}",
            "--encoder",
            "none",
            "--no-rrd",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "no ground truth: poses written (poses.tum), not scored" in result.output
    assert "a bag holds none unless told (--groundtruth FILE.txt or --gt-frames WORLD:CAMERA)" in result.output
    (folder,) = (tmp_path / "outputs" / "loc").iterdir()
    assert folder.name == "demo_tum"  # demo_tum.bag's stem
    (run,) = folder.iterdir()
    summary = json.loads((run / "results.json").read_text())["summary"]
    poses = [line for line in (run / "poses.tum").read_text().splitlines() if line and not line.startswith("#")]
    assert len(poses) == round(summary["frames"] * summary["localized"]) >= 1


@pytest.mark.parametrize(
    "args, text",
    [
        (["--detector", "file:x"], "a ROS bag holds no map; pass --map FILE.map.npz"),
        (
            ["--map", "MAP"],
            "a ROS bag has no annotations to detect from; pass --detector file:DETECTIONS.json (e.g. a TUM "
            "folder run's, matched by colour stamp) or --detector yolo",
        ),
        (["--map", "MAP", "--detector", "file:DET", "--rgb-topic", "/nope"], "--rgb-topic /nope: no such topic"),
        (
            ["--map", "MAP", "--detector", "file:DET", "--window", "2", "--odometry", "tf:world:nowhere"],
            "--odometry tf:world:nowhere: /tf does not connect world to nowhere",
        ),
    ],
)
def test_cli_refusals_are_one_line(recording, tmp_path, monkeypatch, args, text):
    monkeypatch.chdir(tmp_path)
    args = [
        str(recording["map"]) if a == "MAP" else f"file:{recording['detections']}" if a == "file:DET" else a
        for a in args
    ]
    result = RUNNER.invoke(app, ["run", str(recording["mcap"]), "--no-rrd", *args])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and text in lines[0], result.output
    assert not (tmp_path / "outputs").exists()


def test_a_window_on_bag_odometry_matches_ground_truth_odometry(recording, tmp_path):
    """tf:world:CAMERA is the ground truth itself: a window fused by it decides as one fused by exact ground truth."""
    camera = f"world:{recording['frames']['tum']}"
    bag = BagOptions(gt_frames=camera)
    by_tf = localized(recording, recording["ros1"], tmp_path / "tf", bag, window=3, odometry=f"tf:{camera}")
    by_truth = localized(recording, recording["ros1"], tmp_path / "gt", bag, window=3, odometry="groundtruth")
    comparison = compare(decisions(by_truth), decisions(by_tf))
    assert comparison.differing == {}, comparison.report()
    assert by_tf["run"]["window"]["odometry"]["name"] == f"tf:{camera}"


def test_inspect_lists_topics_and_says_what_it_reads(recording):
    result = RUNNER.invoke(app, ["inspect", str(recording["realsense"])])
    assert result.exit_code == 0, result.output
    assert "/camera/color/image_raw/compressed  sensor_msgs/msg/CompressedImage  8 messages" in result.output
    assert "encoding 16UC1" in result.output and "encoding jpeg" in result.output
    assert "reads colour: /camera/color/image_raw/compressed (the only colour image topic)" in result.output
    assert "reads camera_info: /camera/color/camera_info (the only CameraInfo topic)" in result.output


def test_the_benchmark_takes_a_bag_with_its_default_map(recording, folder_run, tmp_path, monkeypatch):
    """clipclique-bench BAG reads outputs/maps/<the bag's stem>.map.npz, as it reads every scene's (without it, one
    line says a bag holds none) and decides as the folder; unscored: the benchmark passes no ground truth to a bag."""
    from clipclique.benchmark.cli import app as bench

    monkeypatch.chdir(tmp_path)
    args = [
        str(recording["mcap"]),
        "--detector",
        f"file:{recording['detections']}",
        "--encoder",
        "none",
        "--out",
        "bench",
        "--cache",
        "cache",
        "-q",
    ]
    missing = RUNNER.invoke(bench, args)
    assert missing.exit_code == 2 and "no map for the bag" in missing.output and "a bag holds none" in missing.output
    (tmp_path / "outputs" / "maps").mkdir(parents=True)
    (tmp_path / "outputs" / "maps" / "demo_tum.map.npz").write_bytes(recording["map"].read_bytes())
    result = RUNNER.invoke(bench, args)
    assert result.exit_code == 0, result.output
    (results,) = (tmp_path / "bench" / "demo_tum").glob("*/results.json")
    unscored = [frame | {"translation_error_m": None, "rotation_error_deg": None} for frame in decisions(folder_run)]
    comparison = compare(unscored, decisions(read_results(results)))
    assert comparison.frames == 8 and comparison.differing == {}, comparison.report()


@pytest.mark.parametrize("given", ["options", "plan"])
def test_the_benchmark_takes_the_bag_options_of_a_run(recording, folder_run, tmp_path, monkeypatch, given):
    """--gt-frames (and every other bag option) as clipclique-loc run takes it, on the command line or as a plan
    file's key: the benchmark's bag run is scored, and decides every frame as the folder's run."""
    from clipclique.benchmark.cli import app as bench

    monkeypatch.chdir(tmp_path)
    camera = f"world:{recording['frames']['tum']}"
    inputs = {"detector": f"file:{recording['detections']}", "encoder": "none", "map": str(recording["map"]),
              "gt_frames": camera, "rgb_topic": "/camera/rgb/image_color"}
    if given == "options":
        args = [str(recording["mcap"])] + [part for key, value in inputs.items()
                                           for part in (f"--{key.replace('_', '-')}", value)]
    else:
        lines = [f"scenes = [{json.dumps(str(recording['mcap']))}]"]
        lines += [f"{key} = {json.dumps(value)}" for key, value in inputs.items()]
        (tmp_path / "plan.toml").write_text("\n".join(lines) + "\n")
        args = ["--plan", "plan.toml"]
    result = RUNNER.invoke(bench, [*args, "--out", "bench", "--cache", "cache", "-q"])
    assert result.exit_code == 0, result.output
    (results,) = (tmp_path / "bench" / "demo_tum").glob("*/results.json")
    (key,) = (tmp_path / "cache").glob("*/key.json")  # the topic read keys the perception cache
    assert json.loads(key.read_text())["bag_reading"] == ["/camera/rgb/image_color", None, None, None]
    comparison = compare(decisions(folder_run), decisions(read_results(results)))
    assert comparison.frames == 8 and comparison.differing == {}, comparison.report()
