"""Hostile ROS bags against `clipclique-loc run` and `inspect` (issue 36): each ends with exit code 2 and one line
naming the bag (and the topic or option at fault), no traceback, and no output folder left behind.

The bags are ROS 2 mcap files written with rosbags' own writer from two-frame 16 x 12 images, each with one
defect; the truncated ones are a demo_tum bag (ROS 1 and mcap) cut short.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from clipclique.backends import load_encoder
from clipclique.io.mapfile import save_map
from clipclique.localization.cli import app
from clipclique.mapping.build import build_map
from clipclique.resolve import open_scene

RUNNER = CliRunner()
K = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
IMAGE, INFO = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"


@pytest.fixture(scope="module")
def inputs(demo_data, bag_tools, tmp_path_factory) -> dict[str, Path]:
    """A map (of demo_tum, which every bag here is named after), a detection file listing no detection in the first
    frames (by index), and a good demo_tum bag."""
    root = tmp_path_factory.mktemp("bag-fuzz")
    folder = demo_data("demo_tum") / "demo" / "demo_tum"
    map, _ = build_map(open_scene(str(folder)), load_encoder("none"))
    save_map(map, root / "demo_tum.map.npz")
    (root / "empty.json").write_text(json.dumps([{"file_name": str(i), "detections": []} for i in range(8)]))
    return {
        "map": root / "demo_tum.map.npz",
        "detections": root / "empty.json",
        "ros1": bag_tools.write_bag(folder, root / "good" / "demo_tum.bag"),
        "mcap": bag_tools.write_bag(folder, root / "good-mcap" / "demo_tum", "mcap"),
    }


def write(bag_tools, path: Path, messages: list[tuple[str, str, float, Callable]]) -> Path:
    """A ROS 2 mcap bag at `path` of (topic, type, stamp, make(store, stamp)) messages."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = bag_tools.typestore(False)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for topic, msgtype, stamp, make in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], int(stamp * 1e9), store.serialize_cdr(make(store, stamp), msgtype))
    return path


def colour(pixels: np.ndarray | None = None, encoding: str = "rgb8", frame: str = "cam") -> Callable:
    pixels = np.full((12, 16, 3), 100, np.uint8) if pixels is None else pixels
    return lambda bag_tools: lambda store, stamp: bag_tools.image(store, stamp, frame, pixels, encoding, False)


def depth(frame: str = "cam") -> Callable:
    return lambda bag_tools: (
        lambda store, stamp: bag_tools.image(store, stamp, frame, np.full((12, 16), 2.0, np.float32), "32FC1", False)
    )


def info(size: tuple[int, int] = (12, 16)) -> Callable:
    return lambda bag_tools: lambda store, stamp: bag_tools.camera_info(store, stamp, "cam", size, K, False)


def scene(*parts: tuple[str, str, Callable], stamps=(1.0, 2.0), offsets: dict[str, float] | None = None) -> list:
    return [
        (topic, msgtype, t + (offsets or {}).get(topic, 0.0), make) for t in stamps for topic, msgtype, make in parts
    ]


GOOD = [("/cam/image", IMAGE, colour()), ("/cam/depth", IMAGE, depth()), ("/cam/camera_info", INFO, info())]
BAGS = {  # name -> (messages, extra options, text the line must hold)
    "two-colour-topics": (
        scene(*GOOD, ("/other/image", IMAGE, colour())),
        [],
        "2 colour Image or CompressedImage topics (/cam/image, /other/image); name the one to read "
        "with --rgb-topic TOPIC",
    ),
    "no-camera-info": (scene(*GOOD[:2]), [], "no sensor_msgs/CameraInfo topic: the camera's intrinsics are unknown"),
    "no-such-topic": (scene(*GOOD), ["--depth-topic", "/nope"], "--depth-topic /nope: no such topic"),
    "not-an-image-topic": (
        scene(*GOOD),
        ["--rgb-topic", "/cam/camera_info"],
        "--rgb-topic /cam/camera_info is a sensor_msgs/msg/CameraInfo",
    ),
    "size-disagrees": (
        scene(GOOD[0], GOOD[1], ("/cam/camera_info", INFO, info((24, 32)))),
        [],
        "image is 16 x 12, its CameraInfo (/cam/camera_info) 32 x 24",
    ),
    "unknown-encoding": (
        scene(("/cam/image", IMAGE, colour(np.zeros((12, 16, 4), np.uint8), "rgba8")), *GOOD[1:]),
        [],
        "colour encoding 'rgba8' is not read",
    ),
    "zero-sized": (
        scene(("/cam/image", IMAGE, colour(np.zeros((0, 16, 3), np.uint8))), *GOOD[1:]),
        [],
        "image is 16 x 0 pixels (empty)",
    ),
    "no-colour-partner": (
        scene(*GOOD, offsets={"/cam/depth": 0.3}),
        [],
        "no image of /cam/image (2) has a depth image of /cam/depth (2) within 0.02 s",
    ),
    "bad-depth-scale": (scene(*GOOD), ["--depth-scale", "-1"], "--depth-scale -1: metres per depth unit"),
    "no-gt-frame": (
        scene(*GOOD),
        ["--gt-frames", "world:cam"],
        "--gt-frames world:cam: /tf does not connect world to cam",
    ),
}


def refused(result, *texts: str) -> str:
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("clipclique-loc: error: "), result.output
    assert "Traceback" not in result.output and all(text in lines[0] for text in texts), result.output
    return lines[0]


@pytest.mark.parametrize("name", BAGS)
def test_a_hostile_bag_is_one_line(inputs, bag_tools, tmp_path, monkeypatch, name):
    messages, options, text = BAGS[name]
    bag = write(bag_tools, tmp_path / "demo_tum", [(t, m, s, make(bag_tools)) for t, m, s, make in messages])
    monkeypatch.chdir(tmp_path)
    result = RUNNER.invoke(
        app,
        [
            "run",
            str(bag),
            "--map",
            str(inputs["map"]),
            "--detector",
            f"file:{inputs['detections']}",
            "--no-rrd",
            *options,
        ],
    )
    refused(result, str(bag), text)
    assert not (tmp_path / "outputs").exists()


@pytest.mark.parametrize("storage", ["ros1", "mcap"])
@pytest.mark.parametrize("keep", [0.3, 0.7])
def test_a_truncated_bag_is_one_line(inputs, tmp_path, monkeypatch, storage, keep):
    good = inputs[storage] if storage == "ros1" else inputs[storage] / "demo_tum.mcap"
    cut = tmp_path / good.name
    data = good.read_bytes()
    cut.write_bytes(data[: int(len(data) * keep)])
    monkeypatch.chdir(tmp_path)
    result = RUNNER.invoke(
        app, ["run", str(cut), "--map", str(inputs["map"]), "--detector", f"file:{inputs['detections']}", "--no-rrd"]
    )
    refused(result, str(cut))
    assert not (tmp_path / "outputs").exists()


def test_an_unknown_storage_plugin_is_one_line(inputs, tmp_path):
    folder = tmp_path / "demo_tum"
    folder.mkdir()
    text = (
        (inputs["mcap"] / "metadata.yaml").read_text().replace("storage_identifier: mcap", "storage_identifier: lmdb")
    )
    (folder / "metadata.yaml").write_text(text)
    (folder / "demo_tum.lmdb").write_bytes(b"\0" * 64)
    refused(RUNNER.invoke(app, ["inspect", str(folder)]), str(folder), "not a readable ROS bag")


def test_inspect_says_why_it_cannot_choose(inputs, bag_tools, tmp_path):
    messages = BAGS["two-colour-topics"][0]
    bag = write(bag_tools, tmp_path / "demo_tum", [(t, m, s, make(bag_tools)) for t, m, s, make in messages])
    result = RUNNER.invoke(app, ["inspect", str(bag)])
    assert result.exit_code == 1
    assert "/other/image  sensor_msgs/msg/Image  2 messages" in result.output
    assert "cannot read it as is: " in result.output and "--rgb-topic TOPIC" in result.output
