"""`clipclique-loc convert BAG --to-tum DIR`: a demo_tum folder written as bags (ROS 1 rgb8/32FC1, RealSense-style
ROS 2 JPEG/16UC1) and converted back reads, through the TUM reader, as the bag's own frames: the same colour
pixels, depth within one TUM unit (1/5000 m) with missing pixels missing, the CameraInfo K and the /tf poses."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from clipclique.datasets import BagOptions, open_sequence
from clipclique.datasets.totum import depth_units
from clipclique.datasets.tum import DEPTH_FACTOR, TumSequence
from clipclique.localization.cli import app

RUNNER = CliRunner()
STORAGES = {"tum": ("ros1", "rec.bag"), "realsense": ("sqlite3", "rec")}
ALL_FILES = "rgb/, depth/, rgb.txt, depth.txt, intrinsics.txt, groundtruth.txt"


@pytest.fixture(scope="module")
def recording(demo_data, bag_tools, tmp_path_factory) -> dict:
    """The demo_tum folder and its bag in each layout."""
    root = tmp_path_factory.mktemp("bag-convert")
    folder = demo_data("demo_tum") / "demo" / "demo_tum"
    bags = {
        layout: bag_tools.write_bag(folder, root / layout / name, storage, layout)
        for layout, (storage, name) in STORAGES.items()
    }
    return {"folder": folder, "bags": bags, "frames": {layout: bag_tools.LAYOUTS[layout]["frame"] for layout in bags}}


def convert(bag: Path, out: Path, *args: str):
    result = RUNNER.invoke(app, ["convert", str(bag), "--to-tum", str(out), *args])
    assert result.exit_code == 0, result.output
    return result


@pytest.mark.parametrize("layout", list(STORAGES))
def test_a_converted_bag_reads_as_the_bags_frames(recording, tmp_path, layout):
    gt_frames = f"world:{recording['frames'][layout]}"
    out = tmp_path / "converted"
    result = convert(recording["bags"][layout], out, "--gt-frames", gt_frames)
    bag = open_sequence(str(recording["bags"][layout]), bag=BagOptions(gt_frames=gt_frames))
    assert result.output.splitlines()[-1] == f"wrote 4 frames (4 with ground truth) to {out}/ ({ALL_FILES})"
    tum = open_sequence(str(out))
    assert isinstance(tum, TumSequence) and len(tum) == len(bag) == 4
    assert np.allclose(tum.timestamps, bag.timestamps, atol=1e-6, rtol=0)
    assert np.allclose(tum.intrinsics, bag.intrinsics, atol=1e-6, rtol=0)  # the CameraInfo K
    original = open_sequence(str(recording["folder"]))
    for i in range(len(bag)):
        got, want = tum[i], bag[i]
        assert got.name == want.name == f"{bag.timestamps[i]:.6f}"
        assert np.array_equal(got.rgb, want.rgb)  # PNG keeps the bag's decoded pixels, JPEG's too
        if layout == "realsense":  # ... which are JPEG's: near the folder's
            assert np.abs(got.rgb.astype(int) - original[i].rgb).mean() < 6
        valid = want.depth > 0
        assert 0.5 < valid.mean() < 1 and np.array_equal(got.depth > 0, valid)  # missing (NaN, 0) stays missing
        assert np.abs(got.depth - want.depth)[valid].max() <= 1 / DEPTH_FACTOR
        assert np.allclose(got.intrinsics, want.intrinsics, atol=1e-6, rtol=0)
        assert np.allclose(got.pose.matrix(), want.pose.matrix(), atol=1e-5, rtol=0)


def test_without_ground_truth_there_is_no_groundtruth_file(recording, tmp_path):
    out = tmp_path / "converted"
    result = convert(recording["bags"]["tum"], out)
    assert "a bag holds none unless told (--groundtruth FILE.txt or --gt-frames WORLD:CAMERA)" in result.output
    assert result.output.splitlines()[-1] == (
        f"wrote 4 frames (0 with ground truth) to {out}/ (rgb/, depth/, rgb.txt, depth.txt, intrinsics.txt)"
    )
    assert sorted(p.name for p in out.iterdir()) == ["depth", "depth.txt", "intrinsics.txt", "rgb", "rgb.txt"]
    assert open_sequence(str(out)).poses == [None] * 4


def test_stride_and_max_frames_choose_the_frames(recording, tmp_path):
    out = tmp_path / "converted"
    groundtruth = recording["folder"] / "groundtruth.txt"
    result = convert(recording["bags"]["tum"], out, "--stride", "2", "--max-frames", "1", "-q",
                     "--groundtruth", str(groundtruth))
    assert result.output.splitlines() == [f"wrote 1 frames (1 with ground truth) to {out}/ ({ALL_FILES})"]
    bag = open_sequence(str(recording["bags"]["tum"]))
    assert (out / "rgb.txt").read_text().splitlines()[1:] == [f"{bag.frame_name(0)} rgb/{bag.frame_name(0)}.png"]
    convert(recording["bags"]["tum"], tmp_path / "odd", "--stride", "2", "-q")
    assert [frame.name for frame in open_sequence(str(tmp_path / "odd"))] == [bag.frame_name(0), bag.frame_name(2)]


def test_an_empty_folder_is_written_into(recording, tmp_path):
    (tmp_path / "empty").mkdir()
    convert(recording["bags"]["tum"], tmp_path / "empty", "-q")
    assert len(open_sequence(str(tmp_path / "empty"))) == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty"]  # no staging folder left beside it
    assert (tmp_path / "empty").stat().st_mode & 0o777 == 0o777 & ~current_umask()  # as mkdir makes it, not 0700


def current_umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def test_depth_units_are_tum_units_with_nan_missing():
    metres = np.array([[1.0, np.nan, 0.0, -2.0], [np.inf, 0.00011, 13.107, 20.0]], np.float32)
    assert depth_units(metres).tolist() == [[5000, 0, 0, 0], [0, 1, 65535, 0]]
    assert depth_units(metres).dtype == np.uint16
