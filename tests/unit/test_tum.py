"""TUM RGB-D reader and our object annotations, on a tiny sequence written here in the official formats."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.datasets import open_sequence
from clipclique.datasets.tum import INTRINSICS, TumSequence, associate
from clipclique.errors import DatasetError


def test_association_pairs_nearest_and_drops_unmatched():
    np.testing.assert_array_equal(associate(np.array([1.0, 2.0, 3.0, 4.0]), np.array([3.015, 0.99, 2.5, 4.03])),
                                  [1, -1, 0, -1])
    np.testing.assert_array_equal(associate(np.array([1.0]), np.array([])), [-1])


def test_frames_depth_and_poses(tmp_path, tum_sequence):
    tum_sequence(tmp_path)
    seq = open_sequence("fr2", tmp_path)
    assert isinstance(seq, TumSequence) and seq.kind == "tum"
    assert len(seq) == 3  # the 0.2 s frame has no depth within 20 ms
    np.testing.assert_allclose(seq.timestamps - 1311868164.0, [0.0013, 0.1013, 0.3013], atol=1e-6)
    assert seq.depth_files[1].endswith("1311868164.111000.png")
    frame = seq[2]
    assert frame.depth[240, 320] == pytest.approx(2.0) and frame.depth[0, 0] == 0
    # Nearest ground truth to t0 + 0.3013 is the sample at t0 + 0.30 (k = 35).
    np.testing.assert_allclose(frame.pose.translation, [1.35, 2.0, 3.0], atol=1e-4)
    np.testing.assert_allclose(frame.pose.rotation, Rotation.from_euler("z", 0.35).as_matrix(), atol=1e-5)
    fx, fy, cx, cy = INTRINSICS["freiburg2"]
    np.testing.assert_allclose(frame.intrinsics, [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])


def test_annotations_become_world_points(tmp_path, tum_sequence):
    tum_sequence(tmp_path)
    seq = open_sequence("fr2", tmp_path)
    assert seq.object_classes() == {4: "monitor", 9: "cup"}
    assert seq[0].instances[240, 320] == 4 and seq[1].instances is None
    instances = {i.instance_id: i for i in seq.instances()}
    monitor, cup = instances[4], instances[9]
    assert monitor.description == "a black monitor, wide" and cup.description == "a photo of a cup"
    # Frame 0 pose: nearest sample to t0 + 0.0013 is t0 (k = 5): yaw 0.05, t = (1.05, 2, 3).
    pose_rot, pose_t = Rotation.from_euler("z", 0.05).as_matrix(), np.array([1.05, 2.0, 3.0])
    camera = (monitor.points - pose_t) @ pose_rot  # back to the camera frame
    fx, fy, cx, cy = INTRINSICS["freiburg2"]
    np.testing.assert_allclose(camera[:, 2], 2.0, atol=1e-6)
    u, v = camera[:, 0] * fx / 2.0 + cx, camera[:, 1] * fy / 2.0 + cy
    assert u.min() == pytest.approx(300) and u.max() == pytest.approx(338) and v.min() == pytest.approx(200)
    assert len(monitor.points) == 20 * 40  # every 2nd row and column of the 80 x 40 mask
    assert len(cup.points) == 20 * 40


def test_groundtruth_is_read_strictly(tmp_path, tum_sequence):
    folder = tum_sequence(tmp_path)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    lines[3] = "1311868164.0000 1.0 2.0 3.0 0 0 0"
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"groundtruth\.txt, line 4: expected 8 numbers"):
        open_sequence("fr2", tmp_path)


def test_intrinsics_need_a_known_camera_or_a_file(tmp_path, tum_sequence):
    folder = tum_sequence(tmp_path)
    renamed = folder.rename(folder.parent / "my_sequence")
    with pytest.raises(DatasetError, match="no freiburg1/2/3 and there is no intrinsics.txt"):
        open_sequence(str(renamed))
    (renamed / "intrinsics.txt").write_text("# fx fy cx cy\n600 601 320 240\n")
    np.testing.assert_allclose(open_sequence(str(renamed)).intrinsics, [[600, 0, 320], [0, 601, 240], [0, 0, 1]])


def test_annotation_errors_name_the_file(tmp_path, tum_sequence):
    folder = tum_sequence(tmp_path)
    (folder / "annotations" / "objects.csv").write_text("id,class,description\n4,monitor,x\n")
    with pytest.raises(DatasetError,
                       match=r"instances/1311868164\.001300\.png: object id 9 is not in annotations/objects\.csv"):
        open_sequence("fr2", tmp_path).instances()
    (folder / "annotations" / "objects.csv").write_text("id,label\n4,monitor\n")
    with pytest.raises(DatasetError, match=r"objects\.csv: header must be 'id,class,description'"):
        open_sequence("fr2", tmp_path).object_classes()
    (folder / "annotations" / "objects.csv").write_text("id,class,description\n4,monitor,x\nfour,cup,y\n")
    with pytest.raises(DatasetError, match=r"objects\.csv, line 3: id 'four' is not an integer"):
        open_sequence("fr2", tmp_path).object_classes()


def test_missing_sequence_says_where_and_where_from(tmp_path):
    with pytest.raises(DatasetError, match=r"tum/rgbd_dataset_freiburg3_long_office_household/.*cvg\.cit\.tum\.de"):
        open_sequence("fr3", tmp_path)
