"""The embedded demo: deterministic bytes, consistent ground truth, and the hard parts of real rooms."""

from __future__ import annotations

import dataclasses
import hashlib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from clipclique.datasets import READERS, STRUCTURE_CLASSES, open_sequence
from clipclique.errors import DatasetError
from clipclique.perception.depth import backproject
from clipclique.perception.raycast import MeshRaycaster
from clipclique.resolve import default_detector, open_scene
from clipclique.sim.demo import DEMO_SCENES, DemoSpec, ensure_scene, generate
from clipclique.sim.procedural import PALETTE, make_room, make_walk

SMALL = {name: dataclasses.replace(spec, num_frames=4, width=160, height=120) for name, spec in DEMO_SCENES.items()}


def small_demo(root: Path, name: str) -> Path:
    """A 4-frame, 160 x 120 demo scene where ensure_scene will find it."""
    folder = root / "demo" / name
    folder.mkdir(parents=True)
    generate(folder, name, SMALL[name])
    return folder


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("name", ["demo", "demo_tum", "demo_apartment", "demo_desk"])
def test_same_seed_same_bytes(tmp_path, name):
    first, second = digest(small_demo(tmp_path / "a", name)), digest(small_demo(tmp_path / "b", name))
    assert first == second
    assert len(first) > 12  # mesh/annotation files plus 4 frames of images


def test_ensure_scene_reuses_a_finished_scene(tmp_path):
    folder = small_demo(tmp_path, "demo")
    assert ensure_scene("demo", tmp_path) == folder  # marker present: nothing regenerated
    assert len(open_scene("demo", tmp_path)) == 4


def test_readers_never_generate_and_a_generated_scene_is_an_ordinary_dataset_folder(tmp_path):
    with pytest.raises(DatasetError, match="unknown scene 'demo'"):
        open_sequence("demo", tmp_path)
    assert not (tmp_path / "demo").exists()
    for name, kind, own in (("demo", "scannet", "gt"), ("demo_desk", "tum", "annotations")):
        sequence = open_sequence(str(small_demo(tmp_path, name)))  # the folder, read as any dataset's
        assert type(sequence) is READERS[kind] and sequence.kind == kind and sequence.synthetic
        assert sequence.default_detector == own  # the reader's; the generated scene's own comes from clipclique.sim
        assert default_detector(sequence) == {"demo": "simulated", "demo_desk": "simulated-yolo"}[name]
        descriptions = sequence.descriptions()
        assert set(descriptions) == set(sequence.object_classes()) and len(descriptions) > 10
        assert all(text.startswith("a ") for text in descriptions.values())


def mesh_distances(room, points: np.ndarray) -> np.ndarray:
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(room.vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(room.faces)
    scene.add_triangles(mesh)
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


@pytest.mark.parametrize("name", ["demo", "demo_tum", "demo_apartment", "demo_desk"])
def test_frames_agree_with_the_scene_geometry(tmp_path, name):
    """Depth + intrinsics + ground-truth pose put every pixel on the mesh, and instance ids on their object."""
    small_demo(tmp_path, name)
    sequence = open_scene(name, tmp_path)
    room = SMALL[name].room()
    owner = room.segment_objects[room.vertex_segments] + 1  # instance id of every vertex
    for frame in sequence:
        labelled = (frame.instances > 0) & (frame.depth > 0)
        points = frame.pose.apply(backproject(frame.depth, frame.intrinsics, labelled))
        distances = mesh_distances(room, points)
        assert np.median(distances) < 0.015 and np.quantile(distances, 0.95) < 0.05
        ids = frame.instances[labelled]
        for object_id in np.unique(ids)[:8]:
            vertices = room.vertices[owner == object_id]
            inside = np.all((points[ids == object_id] >= vertices.min(0) - 0.05)
                            & (points[ids == object_id] <= vertices.max(0) + 0.05), axis=1)
            assert inside.mean() > 0.95, (name, frame.name, object_id)


@pytest.mark.parametrize("name", ["demo", "demo_tum"])
def test_rooms_have_many_objects_of_repeated_classes(name):
    room = make_room(DEMO_SCENES[name].seed)
    objects = [o for o in room.objects if o.category not in STRUCTURE_CLASSES]
    counts = Counter(o.category for o in objects)
    assert 30 <= len(objects) <= 60
    assert counts["chair"] >= 4 and counts["cup"] >= 2 and counts["book"] >= 3 and counts["monitor"] == 2
    assert all(any(word in o.description.split() for word in PALETTE) for o in objects)
    # Objects of one class in one group never share a colour word: "the red chair" names one chair.
    chairs = [o.description for o in objects if o.category == "chair"]
    assert len(set(chairs)) == len(chairs)


@pytest.mark.parametrize("name", ["demo", "demo_tum"])
def test_walk_sees_two_to_eight_objects_in_most_frames(name):
    spec = dataclasses.replace(DEMO_SCENES[name], width=160, height=120)
    room = make_room(spec.seed)
    walk = make_walk(room, spec.seed, 40, spec.duration_s)
    raycaster = MeshRaycaster(room.vertices, room.faces)
    objects = room.face_objects()
    structure = {o.object_id for o in room.objects if o.category in STRUCTURE_CLASSES}
    visible = []
    for pose in walk.poses(walk.times):
        faces = raycaster.render(spec.intrinsics(), pose, (spec.height, spec.width)).faces
        ids, pixels = np.unique(objects[faces[faces >= 0]], return_counts=True)
        visible.append(sum(1 for i, n in zip(ids, pixels) if i not in structure and n >= 40))
    visible = np.array(visible)
    assert np.mean((visible >= 2) & (visible <= 8)) >= 0.7
    assert visible.min() >= 1
    # The camera moves like a person: eye height and never more than ~0.6 m between frames 1.5 s apart.
    positions = np.array([p.translation for p in walk.poses(walk.times)])
    assert positions[:, 2].min() > 1.2 and positions[:, 2].max() < 1.8
    assert np.linalg.norm(np.diff(positions, axis=0), axis=1).max() < 0.6


def test_depth_has_sensor_noise_and_holes(tmp_path):
    small_demo(tmp_path, "demo")
    frame = open_scene("demo", tmp_path)[0]
    assert 0.005 < np.mean(frame.depth == 0) < 0.2  # holes at edges and at random
    # Depth is quantized to millimetres and noisy: not a smooth rendering.
    valid = frame.depth[frame.depth > 0]
    np.testing.assert_allclose(valid * 1000, np.round(valid * 1000), atol=1e-3)


def test_spec_intrinsics_scale_with_the_image():
    full, half = DemoSpec("scannet", 0), DemoSpec("scannet", 0, width=320, height=240)
    np.testing.assert_allclose(half.intrinsics()[:2], full.intrinsics()[:2] / 2)


def test_processes_generating_one_scene_at_once_generate_it_once(tmp_path, monkeypatch):
    """Test workers (pytest -n 2) and two commands started together share one generation: the second waits on the
    first's lock and takes its scene (before, it deleted the folder the first had just moved into place)."""
    import threading
    import time

    import clipclique.sim.demo as demo

    calls = []

    def slow_small(folder, name, spec, progress=None):
        calls.append(name)
        time.sleep(0.3)  # long enough for the other caller to reach the lock
        generate(folder, name, SMALL[name])

    monkeypatch.setattr(demo, "generate", slow_small)
    folders = []
    callers = [threading.Thread(target=lambda: folders.append(ensure_scene("demo", tmp_path))) for _ in range(2)]
    for caller in callers:
        caller.start()
    for caller in callers:
        caller.join()
    assert calls == ["demo"] and folders == [tmp_path / "demo" / "demo"] * 2
    assert len(open_scene("demo", tmp_path)) == 4
    assert sorted(p.name for p in (tmp_path / "demo").iterdir()) == [".demo.lock", "demo"]  # no staging left


def test_ensure_scene_never_deletes_a_folder_it_did_not_write(tmp_path):
    from clipclique.errors import DatasetError

    mine = tmp_path / "demo" / "demo"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("a user's file")
    with pytest.raises(DatasetError, match="exists but is not a generated demo scene"):  # it was deleted
        ensure_scene("demo", tmp_path)
    assert (mine / "notes.txt").read_text() == "a user's file"


def test_an_unwritable_data_root_is_a_clear_error(tmp_path):
    from clipclique.errors import DatasetError

    not_a_folder = tmp_path / "data"
    not_a_folder.write_text("a file where the data root should be")
    with pytest.raises(DatasetError, match=r"data/demo: cannot write the demo scene there .*--data-root"):
        ensure_scene("demo", not_a_folder)
