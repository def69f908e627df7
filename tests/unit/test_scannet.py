"""ScanNet reader on a tiny scene written here in the official file formats."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from plyfile import PlyData, PlyElement

from clipclique.datasets import open_sequence
from clipclique.datasets.scannet import ScanNetScene
from clipclique.errors import DatasetError

SCENE = "scene0007_00"
TSV_HEADER = "id\traw_category\tcategory\tcount\tnyu40id\teigen13id\tnyuClass\tnyu40class\teigen13class"
TSV_ROWS = ["2\tchair\tchair\t4646\t5\t4\tchair\tchair\tChair", "10\toffice chair\toffice chair\t1113\t5\t4\tchair\tchair\tChair",
            "1\twall\twall\t8277\t1\t12\twall\twall\tWall"]


def write_scene(root: Path, tsv: bool = False, descriptions: bool = True) -> tuple[Path, dict[str, np.ndarray]]:
    """A scene with an office chair (objectId 0), a plain chair (1) and a wall (2), plus 3 exported frames."""
    folder = root / "scannet" / "scans" / SCENE
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    parts = {
        "office chair": rng.uniform([0, 0, 0], [0.5, 0.5, 1.0], (200, 3)),
        "chair": rng.uniform([2, 0, 0], [2.5, 0.5, 0.9], (150, 3)),
        "wall": rng.uniform([0, 3, 0], [4, 3.05, 2.5], (300, 3)),
    }
    xyz = np.concatenate(list(parts.values()))
    vertex = np.zeros(len(xyz), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1"), ("label", "u2")])
    vertex["x"], vertex["y"], vertex["z"] = xyz.T
    vertex["red"] = 200
    vertex["label"] = np.repeat([10, 2, 1], [200, 150, 300])
    face = np.zeros(2, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[0, 1, 2], [3, 4, 5]]
    PlyData([PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"})]).write(
        str(folder / f"{SCENE}_vh_clean_2.labels.ply"))
    # Segment ids as ScanNet's over-segmentation writes them: arbitrary integers, several per object,
    # one segment (9) in no group.
    segments = np.concatenate([np.repeat([1001, 17], 100), np.repeat([512, 9], [140, 10]), np.full(300, 3)])
    (folder / f"{SCENE}_vh_clean_2.0.010000.segs.json").write_text(json.dumps({"sceneId": SCENE, "segIndices": segments.tolist()}))
    groups = [
        {"id": 0, "objectId": 0, "segments": [1001, 17], "label": "office chair"},
        {"id": 1, "objectId": 1, "segments": [512], "label": "chair"},
        {"id": 2, "objectId": 2, "segments": [3], "label": "wall"},
    ]
    (folder / f"{SCENE}.aggregation.json").write_text(json.dumps({"sceneId": f"scannet.{SCENE}", "appId": "Aggregator.v2", "segGroups": groups}))
    if tsv:
        (root / "scannet" / "scannetv2-labels.combined.tsv").write_text("\n".join([TSV_HEADER, *TSV_ROWS]) + "\n")
    if descriptions:
        (folder / f"{SCENE}_descriptions.json").write_text(json.dumps({"0": "a purple office chair"}))
    for sub in ("color", "depth", "pose", "intrinsic", "instance-filt"):
        (folder / sub).mkdir()
    intrinsics = np.array([[577.0, 0, 319.5, 0], [0, 577.0, 239.5, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    np.savetxt(folder / "intrinsic" / "intrinsic_depth.txt", intrinsics)
    for n in range(3):
        pose = np.eye(4)
        pose[:3, 3] = [n, 0.5, 1.2]
        if n == 1:
            pose[:] = -np.inf  # SensReader writes -inf where tracking was lost
        np.savetxt(folder / "pose" / f"{n}.txt", pose)
        Image.fromarray(np.full((968, 1296, 3), 40 * n, np.uint8)).save(folder / "color" / f"{n}.jpg")
        Image.fromarray(np.full((480, 640), 1500 + n, np.uint16)).save(folder / "depth" / f"{n}.png")
        instance = np.zeros((480, 640), np.uint8)
        instance[100:200, 100:300] = 1  # objectId 0 + 1
        Image.fromarray(instance).save(folder / "instance-filt" / f"{n}.png")
    return folder, parts


def by_id(scene):
    return {i.instance_id: i for i in scene.instances()}


def test_frames_skip_lost_poses_and_read_metres(tmp_path):
    folder, _ = write_scene(tmp_path)
    scene = open_sequence(SCENE, tmp_path)
    assert isinstance(scene, ScanNetScene) and scene.kind == "scannet" and not scene.synthetic
    assert len(scene) == 2  # frame 1 has a -inf pose
    frame = scene[1]
    assert frame.name == "2" and frame.timestamp == 2.0
    np.testing.assert_allclose(frame.pose.translation, [2, 0.5, 1.2])
    assert frame.depth.dtype == np.float32 and frame.depth[0, 0] == pytest.approx(1.502)
    assert frame.rgb.shape == (480, 640, 3)  # colour resampled to the depth image
    np.testing.assert_allclose(frame.intrinsics, [[577, 0, 319.5], [0, 577, 239.5], [0, 0, 1]])
    assert frame.instances.dtype == np.int32 and set(np.unique(frame.instances)) == {0, 1}
    assert frame.instances[150, 150] == 1 and frame.instances[0, 0] == 0


def test_instances_are_segment_groups_with_raw_categories(tmp_path):
    _, parts = write_scene(tmp_path)
    instances = by_id(open_sequence(SCENE, tmp_path))
    assert sorted(instances) == [1, 2, 3]  # objectId + 1
    chair, plain, wall = instances[1], instances[2], instances[3]
    assert (chair.class_name, plain.class_name, wall.class_name) == ("office chair", "chair", "wall")
    np.testing.assert_allclose(chair.points, parts["office chair"], atol=1e-6)
    np.testing.assert_allclose(plain.points, parts["chair"][:140], atol=1e-6)  # segment 9 is in no group
    assert chair.description == "a purple office chair"
    assert plain.description == "a photo of a chair"  # the template when the scene gives none


def test_label_table_maps_raw_categories_to_nyu40(tmp_path):
    write_scene(tmp_path, tsv=True)
    scene = open_sequence(SCENE, tmp_path)
    assert scene.object_classes() == {1: "chair", 2: "chair"}  # the wall is structure
    assert by_id(scene)[3].class_name == "wall"


def test_scene_cloud_is_the_mesh(tmp_path):
    write_scene(tmp_path)
    points, colors = open_sequence(SCENE, tmp_path).scene_cloud()
    assert points.shape == (650, 3) and colors.dtype == np.uint8 and (colors[:, 0] == 200).all()


def test_missing_scene_says_where_and_where_from(tmp_path):
    with pytest.raises(DatasetError, match=r"scannet/scans/scene0001_00.*scan-net\.org"):
        open_sequence("scene0001_00", tmp_path)


def test_segment_count_mismatch_names_both_files(tmp_path):
    folder, _ = write_scene(tmp_path)
    segs = folder / f"{SCENE}_vh_clean_2.0.010000.segs.json"
    segs.write_text(json.dumps({"segIndices": [0, 1, 2]}))
    with pytest.raises(DatasetError, match=r"segs\.json: 3 segIndices for 650 vertices of scene0007_00_vh_clean_2\.labels\.ply"):
        open_sequence(SCENE, tmp_path).instances()


def test_mesh_without_labels_is_rejected(tmp_path):
    folder, _ = write_scene(tmp_path)
    vertex = np.zeros(650, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(folder / f"{SCENE}_vh_clean_2.labels.ply"))
    with pytest.raises(DatasetError, match="vertex property label missing"):
        open_sequence(SCENE, tmp_path).instances()


def test_malformed_pose_names_the_file(tmp_path):
    folder, _ = write_scene(tmp_path)
    (folder / "pose" / "2.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(DatasetError, match=r"pose/2\.txt: expected a 4x4 pose matrix"):
        open_sequence(SCENE, tmp_path)


def test_folder_path_and_data_root_environment(tmp_path, monkeypatch):
    folder, _ = write_scene(tmp_path)
    assert open_sequence(str(folder)).name == SCENE
    monkeypatch.setenv("CLIPCLIQUE_DATA", str(tmp_path))
    assert len(open_sequence(SCENE)) == 2


def test_frames_without_instance_images_project_the_labelled_mesh(tmp_path):
    """A labelled quad 1.5 m in front of frame 0's camera shows up where the measured depth agrees."""
    folder, _ = write_scene(tmp_path)
    ply_path = folder / f"{SCENE}_vh_clean_2.labels.ply"
    vertex = PlyData.read(str(ply_path))["vertex"].data
    quad = np.zeros(4, dtype=vertex.dtype)
    quad["x"], quad["y"], quad["z"] = [-0.5, 0.5, 0.5, -0.5], [0.0, 0.0, 1.0, 1.0], 2.7
    face = np.zeros(2, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[650, 651, 652], [650, 652, 653]]
    PlyData([PlyElement.describe(np.concatenate([vertex, quad]), "vertex"), PlyElement.describe(face, "face")]).write(str(ply_path))
    segs = folder / f"{SCENE}_vh_clean_2.0.010000.segs.json"
    segs.write_text(json.dumps({"segIndices": json.loads(segs.read_text())["segIndices"] + [512] * 4}))  # the plain chair
    depth = np.full((480, 640), 1500, np.uint16)
    depth[:, 320:] = 3000  # right half measures 3 m where the mesh is at 1.5 m: the depth test fails
    Image.fromarray(depth).save(folder / "depth" / "0.png")
    (folder / "instance-filt" / "0.png").unlink()
    instances = open_sequence(SCENE, tmp_path)[0].instances
    # Camera at (0, 0.5, 1.2) looking along +z: the quad covers u, v = 319.5 +- 192 pixels.
    assert instances[240, 200] == 2 and instances[100, 200] == 2
    assert instances[20, 200] == 0 and instances[240, 20] == 0  # outside the quad
    assert instances[240, 400] == 0  # measured depth disagrees with the mesh


@pytest.mark.parametrize(
    "name, text, message",
    [
        (f"{SCENE}_descriptions.json", '{"chair": "a red chair"}', "keys must be ScanNet objectIds"),
        (f"{SCENE}_descriptions.json", '["a red chair"]', "expected a JSON object"),
        (f"{SCENE}.aggregation.json", "[]", "expected a JSON object"),
    ],
)
def test_malformed_json_files_name_the_file(tmp_path, name, text, message):
    folder, _ = write_scene(tmp_path)
    (folder / name).write_text(text)  # were ValueError / AttributeError tracebacks
    with pytest.raises(DatasetError, match=f"{name}: {message}"):
        open_sequence(SCENE, tmp_path).instances()
