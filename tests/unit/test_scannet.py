"""ScanNet reader on a tiny scene written in the official file formats (the scannet_scene fixture)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from plyfile import PlyData, PlyElement

from clipclique.datasets import open_sequence
from clipclique.datasets.scannet import ScanNetScene
from clipclique.errors import DatasetError

SCENE = "scene0007_00"  # the tiny scene the scannet_scene fixture writes (tests/conftest.py)


def by_id(scene):
    return {i.instance_id: i for i in scene.instances()}


def test_frames_skip_lost_poses_and_read_metres(tmp_path, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
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


def test_instances_are_segment_groups_with_raw_categories(tmp_path, scannet_scene):
    _, parts = scannet_scene(tmp_path)
    instances = by_id(open_sequence(SCENE, tmp_path))
    assert sorted(instances) == [1, 2, 3]  # objectId + 1
    chair, plain, wall = instances[1], instances[2], instances[3]
    assert (chair.class_name, plain.class_name, wall.class_name) == ("office chair", "chair", "wall")
    np.testing.assert_allclose(chair.points, parts["office chair"], atol=1e-6)
    np.testing.assert_allclose(plain.points, parts["chair"][:140], atol=1e-6)  # segment 9 is in no group
    assert chair.description == "a purple office chair"
    assert plain.description == "a photo of a chair"  # the template when the scene gives none


def test_label_table_maps_raw_categories_to_nyu40(tmp_path, scannet_scene):
    scannet_scene(tmp_path, tsv=True)
    scene = open_sequence(SCENE, tmp_path)
    assert scene.object_classes() == {1: "chair", 2: "chair"}  # the wall is structure
    assert by_id(scene)[3].class_name == "wall"


def test_scene_cloud_is_the_mesh(tmp_path, scannet_scene):
    scannet_scene(tmp_path)
    points, colors = open_sequence(SCENE, tmp_path).scene_cloud()
    assert points.shape == (650, 3) and colors.dtype == np.uint8 and (colors[:, 0] == 200).all()


def test_missing_scene_says_where_and_where_from(tmp_path):
    with pytest.raises(DatasetError, match=r"scannet/scans/scene0001_00.*scan-net\.org"):
        open_sequence("scene0001_00", tmp_path)


def test_segment_count_mismatch_names_both_files(tmp_path, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    segs = folder / f"{SCENE}_vh_clean_2.0.010000.segs.json"
    segs.write_text(json.dumps({"segIndices": [0, 1, 2]}))
    with pytest.raises(DatasetError,
                       match=r"segs\.json: 3 segIndices for 650 vertices of scene0007_00_vh_clean_2\.labels\.ply"):
        open_sequence(SCENE, tmp_path).instances()


def test_mesh_without_labels_is_rejected(tmp_path, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    vertex = np.zeros(650, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(folder / f"{SCENE}_vh_clean_2.labels.ply"))
    with pytest.raises(DatasetError, match="vertex property label missing"):
        open_sequence(SCENE, tmp_path).instances()


def test_malformed_pose_names_the_file(tmp_path, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    (folder / "pose" / "2.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(DatasetError, match=r"pose/2\.txt: expected a 4x4 pose matrix"):
        open_sequence(SCENE, tmp_path)


def test_folder_path_and_data_root_environment(tmp_path, monkeypatch, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    assert open_sequence(str(folder)).name == SCENE
    monkeypatch.setenv("CLIPCLIQUE_DATA", str(tmp_path))
    assert len(open_sequence(SCENE)) == 2


def test_frames_without_instance_images_project_the_labelled_mesh(tmp_path, scannet_scene):
    """A labelled quad 1.5 m in front of frame 0's camera shows up where the measured depth agrees."""
    folder, _ = scannet_scene(tmp_path)
    ply_path = folder / f"{SCENE}_vh_clean_2.labels.ply"
    vertex = PlyData.read(str(ply_path))["vertex"].data
    quad = np.zeros(4, dtype=vertex.dtype)
    quad["x"], quad["y"], quad["z"] = [-0.5, 0.5, 0.5, -0.5], [0.0, 0.0, 1.0, 1.0], 2.7
    face = np.zeros(2, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[650, 651, 652], [650, 652, 653]]
    PlyData([PlyElement.describe(np.concatenate([vertex, quad]), "vertex"),
             PlyElement.describe(face, "face")]).write(str(ply_path))
    segs = folder / f"{SCENE}_vh_clean_2.0.010000.segs.json"
    # the plain chair
    segs.write_text(json.dumps({"segIndices": json.loads(segs.read_text())["segIndices"] + [512] * 4}))
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
def test_malformed_json_files_name_the_file(tmp_path, name, text, message, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    (folder / name).write_text(text)  # were ValueError / AttributeError tracebacks
    with pytest.raises(DatasetError, match=f"{name}: {message}"):
        open_sequence(SCENE, tmp_path).instances()
