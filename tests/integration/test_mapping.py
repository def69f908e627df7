"""clipclique-map: landmarks from the demo scenes, the CLI's outputs and its errors."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from clipclique.config import FitParams
from clipclique.datasets import STRUCTURE_CLASSES, Instance
from clipclique.io.mapfile import load_map
from clipclique.mapping.build import BuildReport, build_map, fit_landmarks
from clipclique.mapping.cli import app
from clipclique.resolve import open_scene
from clipclique.sim.demo import DEMO_SCENES
from clipclique.sim.procedural import make_room

runner = CliRunner()


@pytest.fixture(scope="module")
def data_root(demo_data):
    return demo_data("demo", "demo_tum")


def object_boxes(name: str) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Instance id -> (min corner, max corner) of each object's mesh vertices."""
    room = make_room(DEMO_SCENES[name].seed)
    owner = room.segment_objects[room.vertex_segments] + 1
    return {o.object_id + 1: (room.vertices[owner == o.object_id + 1].min(0),
                              room.vertices[owner == o.object_id + 1].max(0)) for o in room.objects}


def test_scannet_demo_map_matches_the_objects(data_root):
    sequence = open_scene("demo", data_root)
    map, report = build_map(sequence, encoder=None)
    room = make_room(DEMO_SCENES["demo"].seed)
    objects = [o for o in room.objects if o.category not in STRUCTURE_CLASSES]
    assert report.structure == {"wall": 4, "floor": 1, "ceiling": 1}
    assert ([item for items in report.skipped.values() for item in items]
            == [f"picture #{o.object_id + 1}" for o in objects if o.category == "picture"])
    assert len(map) == len(objects) - 1
    boxes = object_boxes("demo")
    offsets = []
    for k, object_id in enumerate(map.instance_ids):
        category = room.objects[object_id - 1].category
        assert map.class_names[map.class_ids[k]] == category
        assert map.descriptions[k] == room.objects[object_id - 1].description
        low, high = boxes[object_id]
        offsets.append(np.linalg.norm(map.ellipsoids.centers[k] - (low + high) / 2))
        assert np.all((map.ellipsoids.centers[k] > low) & (map.ellipsoids.centers[k] < high))
        assert np.all(map.ellipsoids.axes[k] <= (high - low).max() * 0.75 + 0.02)  # no larger than the object
    # Box-like objects are centred exactly; L-shaped ones (chairs, sofas, a bed with its head
    # board) tilt their PCA box, which moves its centre by up to ~20 cm from the aligned box's.
    assert np.median(offsets) < 0.03 and max(offsets) < 0.25
    assert map.encoder == "none" and map.text_embeddings is None
    assert map.provenance["source"]["name"] == "demo" and map.provenance["source"]["synthetic"] is True
    assert map.provenance["parameters"]["min_points"] == FitParams().min_points


def test_tum_demo_map_from_annotations(data_root):
    map, report = build_map(open_scene("demo_tum", data_root), encoder=None)
    boxes = object_boxes("demo_tum")
    annotated = len(open_scene("demo_tum", data_root).object_classes())
    assert len(map) + sum(len(v) for v in report.skipped.values()) == annotated
    assert len(map) >= 10  # 4 frames see a good part of the room
    for k, object_id in enumerate(map.instance_ids):
        low, high = boxes[object_id]
        assert np.all((map.ellipsoids.centers[k] >= low - 0.05) & (map.ellipsoids.centers[k] <= high + 0.05))


def test_skips_are_counted_by_reason():
    rng = np.random.default_rng(0)
    instances = [
        Instance(1, "cup", "a cup", rng.normal(size=(10, 3))),
        Instance(2, "picture", "a picture", np.column_stack((rng.uniform(0, 1, (500, 2)), np.zeros(500)))),
        Instance(3, "floor", "", rng.normal(size=(500, 3))),
        Instance(4, "chair", "a chair", rng.normal(size=(500, 3)) * [0.3, 0.2, 0.4]),
    ]
    report = BuildReport()
    kept, fits = fit_landmarks(instances, FitParams(), report)
    assert [i.instance_id for i in kept] == [4] and len(fits) == 1
    assert report.structure == {"floor": 1}
    assert report.skipped == {
        "fewer than 30 points": ["cup #1"],
        "degenerate (a semi-axis under 1 cm) or too few points after outlier removal": ["picture #2"],
    }


def test_cli_builds_the_demo_map_and_recording(data_root, tmp_path):
    out = tmp_path / "demo.map.npz"
    result = runner.invoke(app, ["build", "demo", "--data-root", str(data_root), "--out", str(out)])
    assert result.exit_code == 0, result.output
    map = load_map(out)
    assert map.encoder == "simulated-clip" and map.provenance["encoder_simulated"] is True
    assert map.text_embeddings.shape[0] == len(map)
    assert (tmp_path / "demo.map.rrd").stat().st_size > 10_000
    assert "skipped 1" in result.output and "picture" in result.output and "simulated" in result.output
    assert "left out as structure: ceiling x1, floor x1, wall x4" in result.output
    distances = np.linalg.norm(map.ellipsoids.centers[:, None] - map.ellipsoids.centers[None], axis=-1)
    degrees = (distances < 0.8).sum(axis=1) - 1  # brute force, self excluded
    counts = np.bincount(degrees)
    assert counts.sum() == len(map) and len(counts) > 2  # the demo room has isolated and connected landmarks
    assert (f"landmarks per degree (0, 1, 2, ...): {', '.join(str(n) for n in counts)}; "
            f"{counts[0] / len(map):.0%} isolated") in " ".join(result.output.split())


def test_cli_tum_demo_without_encoder_or_recording(data_root, tmp_path):
    out = tmp_path / "t.map.npz"
    result = runner.invoke(app, ["build", "demo_tum", "--data-root", str(data_root), "--out", str(out), "--encoder",
                                 "none", "--no-rrd"])
    assert result.exit_code == 0, result.output
    assert load_map(out).encoder == "none" and "text embeddings: none (--encoder none)" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.map.npz"]


def test_cli_quiet_and_verbose(data_root, tmp_path):
    """-q: where the map is, nothing else; -v: every landmark too."""
    out = tmp_path / "q.map.npz"
    quiet = runner.invoke(app, ["build", "demo", "--data-root", str(data_root), "--out", str(out), "--no-rrd", "-q"])
    assert quiet.exit_code == 0 and quiet.output == f"map: {out}\n"
    verbose = runner.invoke(app, ["build", "demo", "--data-root", str(data_root), "--out", str(out), "--no-rrd", "-v"])
    landmarks = [line for line in verbose.output.splitlines() if ": centre " in line]
    assert verbose.exit_code == 0 and len(landmarks) == len(load_map(out))


def test_the_generating_bar_appears_only_when_there_is_work():
    """Demo data that exists is not 'generating the demo data (first use) 0/?'."""
    from rich.progress import Progress

    from clipclique.mapping.tables import bar_on_first_call

    progress = Progress()
    update = bar_on_first_call(progress, "generating")
    assert progress.tasks == []
    update(1, 4)
    update(2, 4)
    assert [(t.description, t.completed, t.total) for t in progress.tasks] == [("generating", 2, 4)]


@pytest.mark.parametrize(
    "args, message",
    [
        (["build", "scene0000_00"], "scan-net.org"),
        (["build", "fr2"], "cvg.cit.tum.de"),
        (["build", "demo", "--encoder", "clip-please"], "--encoder 'clip-please'"),
        (["build", "nonsense"], "unknown scene 'nonsense'"),
    ],
)
def test_cli_user_errors_are_one_line_exit_2(tmp_path, data_root, args, message):
    root = data_root if "demo" in args else tmp_path
    result = runner.invoke(app, [*args, "--data-root", str(root), "--out", str(tmp_path / "x.npz")])
    assert result.exit_code == 2
    assert message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "x.npz").exists()


class _Scene:
    """A stand-in Sequence with given instances (build_map reads only these attributes)."""

    name, kind, synthetic = "stub", "tum", True

    def __init__(self, root, instances):
        self.root, self._instances = root, instances

    def instances(self):
        return self._instances

    def missing_poses(self):
        return None


def test_a_scene_without_landmarks_is_a_user_error_not_an_invalid_map(tmp_path):
    from clipclique.backends import load_encoder
    from clipclique.errors import DatasetError

    floor = Instance(1, "floor", "", np.random.default_rng(0).normal(size=(500, 3)))
    with pytest.raises(DatasetError, match="no landmarks to map: none of its 1 objects.*1 left out as structure"):
        build_map(_Scene(tmp_path, [floor]), load_encoder("simulated"))
    with pytest.raises(DatasetError, match="no annotated objects.*annotations/objects.csv"):
        build_map(_Scene(tmp_path, []), encoder=None)
