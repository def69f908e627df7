"""clipclique-map import / export end to end on demo_tum: the JSON round trip localizes identically, the
OA-SLAM text round trip keeps the geometry within 1e-6 m, and an aligned import is the sequence's map."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from clipclique.interop.quadric import encode_dual_quadric
from clipclique.io.mapfile import load_map
from clipclique.localization.cli import app as loc_app
from clipclique.mapping.cli import app as map_app

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
RUNNER = CliRunner()


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("maps") / "demo_tum.map.npz"
    result = RUNNER.invoke(map_app, ["build", "demo_tum", "--data-root", str(ROOT / "data"), "--out", str(path),
                                     "--no-rrd", "-q"])
    assert result.exit_code == 0, result.output
    return path


def localize(map_path: Path, out: Path) -> list:
    result = RUNNER.invoke(loc_app, ["run", "demo_tum", "--data-root", str(ROOT / "data"), "--map", str(map_path),
                                     "--out", str(out), "--no-rrd", "--max-frames", "40"])
    assert result.exit_code == 0, result.output
    frames = json.loads((out / "results.json").read_text())["frames"]
    return [[(h["pose"], h["score"], h["correspondences"]) for h in frame["hypotheses"]] for frame in frames]


def test_json_round_trip_localizes_identically(built, tmp_path):
    exported = RUNNER.invoke(map_app, ["export", str(built), "--format", "json", "--out", str(tmp_path / "l.json")])
    assert exported.exit_code == 0 and "wrote 42 landmarks" in exported.output, exported.output
    imported = RUNNER.invoke(map_app, ["import", str(tmp_path / "l.json"), "--encoder", "simulated", "--no-rrd",
                                       "--out", str(tmp_path / "back.map.npz")])
    assert imported.exit_code == 0 and "in the frame of demo_tum, as the file says" in imported.output, imported.output
    poses = localize(built, tmp_path / "a")
    assert sum(map(len, poses)) > 100
    assert localize(tmp_path / "back.map.npz", tmp_path / "b") == poses


def test_text_round_trip_keeps_geometry_and_names_what_it_cannot_write(built, tmp_path):
    out = tmp_path / "map_objects_demo.txt"
    exported = RUNNER.invoke(map_app, ["export", str(built), "--format", "oaslam-txt", "--out", str(out)])
    assert exported.exit_code == 0, exported.output
    assert "left out" in exported.output and "lamp" in exported.output and "office chair as chair" in exported.output
    original = load_map(built)
    imported = RUNNER.invoke(map_app, ["import", str(out), "--encoder", "none", "--no-rrd", "--out",
                                       str(tmp_path / "t.map.npz")])
    assert imported.exit_code == 0, imported.output
    back = load_map(tmp_path / "t.map.npz")
    rows = {i: r for r, i in enumerate(original.instance_ids.tolist())}
    ids = back.provenance["source_object_ids"]
    assert len(ids) == int(exported.output.split("wrote ")[1].split()[0]) > 10
    for row, object_id in enumerate(ids):
        source = rows[object_id]
        assert np.abs(back.ellipsoids.centers[row] - original.ellipsoids.centers[source]).max() < 1e-6
        assert np.abs(np.sort(back.ellipsoids.axes[row]) - np.sort(original.ellipsoids.axes[source])).max() < 1e-6
        quadric = [encode_dual_quadric(e.centers[i], e.axes[i], e.rotations[i])  # the same ellipsoid, any axis order
                   for e, i in ((back.ellipsoids, row), (original.ellipsoids, source))]
        assert np.abs(quadric[0] - quadric[1]).max() < 1e-5
    refused = RUNNER.invoke(loc_app, ["run", "demo_tum", "--data-root", str(ROOT / "data"), "--map",
                                      str(tmp_path / "t.map.npz"),
                                      "--out", str(tmp_path / "r"), "--no-rrd", "--max-frames", "2"])
    assert refused.exit_code == 2 and "not aligned to a sequence" in refused.output  # its own frame: not demo_tum's


def test_a_yolo_run_writes_its_detections_and_a_file_rerun_reproduces_it(monkeypatch, built, tmp_path):
    """`--detector yolo` (a stand-in here: no weights) writes COCO results with RLE masks; `--detector file:` on
    them gives the same poses."""
    from clipclique.interop.coco import reported_classes
    from clipclique.perception import yolo
    from clipclique.perception.detectors import InstanceDetector
    from clipclique.sim.detectors import SimulatedDetector
    from clipclique.types import Detections

    class StandInYolo(yolo.YoloDetector):
        def __init__(self, weights, class_names, confidence=0.25, device=None):
            self.class_names, self.name, self.simulated = class_names, "yolo:stand-in", False
            self.class_map = yolo.coco_to_vocabulary(class_names)
            writable = {class_names.index(name) for name in reported_classes(self.class_map, class_names)}
            self.writable = np.array(sorted(writable))
            self.truth = None

        def detect(self, frame):
            if self.truth is None:
                from clipclique.resolve import open_scene

                objects = open_scene("demo_tum", ROOT / "data").object_classes()
                self.truth = SimulatedDetector(InstanceDetector(objects, self.class_names))
            found = self.truth.detect(frame)
            keep = np.isin(found.class_ids, self.writable)
            return Detections(found.masks[keep], found.boxes[keep], found.class_ids[keep], found.scores[keep],
                              np.full(int(keep.sum()), -1))

    monkeypatch.setattr(yolo.YoloDetector, "load", classmethod(lambda cls, *args: StandInYolo(*args)))
    first = tmp_path / "yolo"
    args = ["run", "demo_tum", "--data-root", str(ROOT / "data"), "--map", str(built), "--no-rrd", "--max-frames", "12"]
    result = RUNNER.invoke(loc_app, [*args, "--detector", "yolo", "--out", str(first)])
    assert result.exit_code == 0, result.output
    entries = json.loads((first / "detections.json").read_text())
    assert len(entries) > 30 and all(set(e["segmentation"]) == {"size", "counts"} for e in entries)
    assert len(json.loads((first / "images.json").read_text())["images"]) == 12
    again = RUNNER.invoke(loc_app, [*args, "--detector", f"file:{first / 'detections.json'}", "--out",
                                    str(tmp_path / "file")])
    assert again.exit_code == 0, again.output

    def poses(folder: Path) -> list:
        frames = json.loads((folder / "results.json").read_text())["frames"]
        return [(f["detections"], [(h["pose"], h["score"]) for h in f["hypotheses"]]) for f in frames]

    assert poses(tmp_path / "file") == poses(first)
