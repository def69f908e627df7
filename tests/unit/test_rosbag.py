"""The ROS bag reader: encodings decoded to the numbers a Frame holds, /tf chained, topics chosen, and a bag
written from a TUM folder read back as the same frames (ROS 1, ROS 2 mcap and sqlite3)."""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from clipclique.datasets import BagOptions, open_sequence
from clipclique.datasets.rosimages import decode_colour, decode_depth
from clipclique.datasets.rostf import TfTree
from clipclique.errors import DatasetError
from clipclique.interop.detections import DetectionFile, FileDetection, FileDetector
from clipclique.types import Frame, Pose


@dataclass
class Img:
    height: int
    width: int
    encoding: str
    step: int
    data: np.ndarray
    is_bigendian: int = 0


@dataclass
class Compressed:
    format: str
    data: np.ndarray


def raw(pixels: np.ndarray, encoding: str, pad: int = 0, big: bool = False) -> Img:
    pixels = pixels.astype(pixels.dtype.newbyteorder(">" if big else "<"))
    rows = pixels.reshape(pixels.shape[0], -1).view(np.uint8)
    padded = np.hstack([rows, np.full((rows.shape[0], pad), 7, np.uint8)])
    return Img(pixels.shape[0], pixels.shape[1], encoding, padded.shape[1], padded.reshape(-1), int(big))


def png(array: np.ndarray, fmt: str = "PNG") -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, fmt)
    return buffer.getvalue()


RGB = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)


def test_colour_encodings_give_rgb():
    assert np.array_equal(decode_colour(raw(RGB, "rgb8"), "m"), RGB)
    assert np.array_equal(decode_colour(raw(RGB[..., ::-1].copy(), "bgr8", pad=3), "m"), RGB)  # row padding skipped
    grey = RGB[..., 0].copy()
    assert np.array_equal(decode_colour(raw(grey, "mono8"), "m"), np.repeat(grey[..., None], 3, axis=2))
    assert np.array_equal(decode_colour(Compressed("png", np.frombuffer(png(RGB), np.uint8)), "m"), RGB)
    jpeg = decode_colour(
        Compressed("jpeg", np.frombuffer(png(np.full((8, 8, 3), 120, np.uint8), "JPEG"), np.uint8)), "m"
    )
    assert jpeg.shape == (8, 8, 3) and abs(int(jpeg.mean()) - 120) <= 2


def test_depth_encodings_give_metres_with_zero_missing():
    metres = np.array([[1.5, np.nan], [0.25, 3.0]], np.float32)
    assert np.array_equal(decode_depth(raw(metres, "32FC1"), "m"), np.nan_to_num(metres))
    mm = np.array([[1500, 0], [250, 3000]], np.uint16)
    assert np.allclose(decode_depth(raw(mm, "16UC1", pad=2, big=True), "m"), [[1.5, 0], [0.25, 3.0]])
    assert np.allclose(decode_depth(raw(mm, "16UC1"), "m", depth_scale=0.0002), [[0.3, 0], [0.05, 0.6]])
    header = struct.pack("<iff", 0, 0.0, 0.0)
    packed = Compressed("16UC1; compressedDepth png", np.frombuffer(header + png(mm), np.uint8))
    assert np.allclose(decode_depth(packed, "m"), [[1.5, 0], [0.25, 3.0]])


def test_compressed_depth_32fc1_is_quantised_inverse_depth():
    """image_transport's codec: A = q (q + 1), B = 1 - A / max_depth, stored = A / depth + B (0 = missing)."""
    quant, max_depth = 100.0, 10.0
    a, b = quant * (quant + 1.0), 1.0 - quant * (quant + 1.0) / max_depth
    depth = np.array([[1.0, 2.0], [0.5, 0.0]], np.float32)
    stored = np.where(depth > 0, a / np.where(depth > 0, depth, 1) + b, 0).round().astype(np.uint16)
    message = Compressed(
        "32FC1; compressedDepth png", np.frombuffer(struct.pack("<iff", 0, a, b) + png(stored), np.uint8)
    )
    decoded = decode_depth(message, "m")
    assert decoded[1, 1] == 0
    assert np.allclose(decoded[depth > 0], depth[depth > 0], rtol=1e-3)


@pytest.mark.parametrize(
    "message, text",
    [
        (raw(RGB, "rgba16"), "colour encoding 'rgba16'"),
        (Img(4, 5, "rgb8", 15, np.zeros(20, np.uint8)), "needs 4 rows of 15 bytes"),
        (Img(0, 5, "rgb8", 15, np.zeros(0, np.uint8)), "empty"),
        (Compressed("jpeg", np.frombuffer(b"not an image", np.uint8)), "unreadable image"),
    ],
)
def test_bad_colour_is_one_line_naming_the_message(message, text):
    with pytest.raises(DatasetError, match="^bag, /rgb: .*" + text):
        decode_colour(message, "bag, /rgb")


@pytest.mark.parametrize(
    "message, text",
    [
        (raw(RGB, "rgb8"), "depth encoding 'rgb8'"),
        (Compressed("jpeg", np.frombuffer(png(RGB, "JPEG"), np.uint8)), "must be compressedDepth"),
        (Compressed("32FC1; compressedDepth", np.zeros(12, np.uint8)), "holds no image"),
        (
            Compressed(
                "32FC1; compressedDepth",
                np.frombuffer(struct.pack("<iff", 0, 0, 0) + png(np.ones((2, 2), np.uint16)), np.uint8),
            ),
            "no quantisation",
        ),
    ],
)
def test_bad_depth_is_one_line_naming_the_message(message, text):
    with pytest.raises(DatasetError, match="^bag, /depth: .*" + text):
        decode_depth(message, "bag, /depth")


@dataclass
class Stamp:
    sec: int
    nanosec: int


@dataclass
class Head:
    stamp: Stamp
    frame_id: str


@dataclass
class Vec:
    x: float
    y: float
    z: float


@dataclass
class Quat:
    x: float
    y: float
    z: float
    w: float


@dataclass
class Tf:
    translation: Vec
    rotation: Quat


@dataclass
class Stamped:
    header: Head
    child_frame_id: str
    transform: Tf


@dataclass
class TfMessage:
    transforms: list


def stamped(t: float, parent: str, child: str, pose: Pose) -> Stamped:
    q = Rotation.from_matrix(pose.rotation).as_quat()
    return Stamped(Head(Stamp(int(t), int(round((t % 1) * 1e9))), parent), child, Tf(Vec(*pose.translation), Quat(*q)))


def test_tf_chains_dynamic_and_static_edges_up_and_down():
    """world -> base (dynamic, 100 Hz) -> camera (static); odom -> base too: camera in world is the chain's
    product at the nearest sample, and base in camera walks the static edge up (inverted)."""
    rng = np.random.default_rng(0)
    tree = TfTree()
    static = Pose(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3))
    tree.add(TfMessage([stamped(0.0, "base", "camera", static)]), True, "bag")
    bases = {}
    for k in range(10):
        bases[k] = Pose(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3))
        tree.add(TfMessage([stamped(100 + 0.01 * k, "/world", "base", bases[k])]), False, "bag")
    poses = tree.poses("world", "camera", np.array([100.031, 100.5]), 0.02)
    assert np.allclose(poses[0].matrix(), bases[3].compose(static).matrix(), atol=1e-12)
    assert poses[1] is None  # no sample within 0.02 s
    up = tree.poses("camera", "base", np.array([100.0]), 0.02)[0]
    assert np.allclose(up.matrix(), static.inverse().matrix(), atol=1e-12)
    with pytest.raises(DatasetError, match="does not connect world to elsewhere"):
        tree.poses("world", "elsewhere", np.array([100.0]), 0.02)


def frame(name: str, timestamp: float, index: int) -> Frame:
    return Frame(
        index, timestamp, np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), np.float32), np.eye(3), None, name=name
    )


def test_detection_files_meet_frames_by_name_then_stamp_then_index():
    one = [FileDetection("cup", np.array([0, 0, 1, 1.0]), 0.9)]
    two = [FileDetection("cup", np.array([0, 0, 2, 2.0]), 0.8)]
    three = [FileDetection("cup", np.array([0, 0, 3, 3.0]), 0.7)]
    detector = FileDetector(Path("d.json"), DetectionFile({"1305031102.175304": one, "2": two, "1305031103.5": three}),
                            ["cup"])
    assert detector.listed(frame("1305031102.175304", 0.0, 9)) is one  # by name
    assert detector.listed(frame("a", 1305031102.19, 9)) is one  # by stamp: 0.0147 s away
    assert detector.listed(frame("a", 1305031102.2, 9)) == []  # 0.0247 s: too far, and no index 9
    assert detector.listed(frame("a", 1305031102.2, 2)) is two  # by index
    assert detector.listed(frame("a", 1305031103.49, 0)) is three


@pytest.mark.parametrize("storage, layout", [("ros1", "tum"), ("mcap", "tum"), ("sqlite3", "realsense")])
def test_a_bag_of_a_tum_folder_reads_as_its_frames(demo_data, bag_tools, tmp_path, storage, layout):
    folder = demo_data("demo_tum") / "demo" / "demo_tum"
    out = bag_tools.write_bag(folder, tmp_path / ("rec.bag" if storage == "ros1" else "rec"), storage, layout)
    tum = open_sequence(str(folder))
    bag = open_sequence(str(out), bag=BagOptions(gt_frames=f"world:{bag_tools.LAYOUTS[layout]['frame']}"))
    assert (bag.kind, bag.name, len(bag), bag.notes()) == ("rosbag", "rec", len(tum), [])
    assert np.allclose(bag.timestamps, tum.timestamps, atol=1e-6, rtol=0)
    for i in range(len(tum)):
        got, want = bag[i], tum[i]
        assert got.name == want.name and np.array_equal(got.intrinsics, want.intrinsics)
        assert np.allclose(got.pose.matrix(), want.pose.matrix(), atol=1e-9)  # /tf with the static edge applied
        if layout == "tum":  # rgb8 and 32FC1: the very pixels
            assert np.array_equal(got.rgb, want.rgb) and np.array_equal(got.depth, want.depth)
        else:  # JPEG colour, millimetre depth: near (5000 units/m rounded to 1000)
            assert np.abs(got.rgb.astype(int) - want.rgb).mean() < 6
            assert np.abs(got.depth - want.depth).max() <= 0.0005 and np.array_equal(got.depth > 0, want.depth > 0)
    if storage == "ros1":
        truth = open_sequence(str(out), bag=BagOptions(groundtruth=folder / "groundtruth.txt"))
        assert all(np.allclose(a.matrix(), b.matrix(), atol=1e-9) for a, b in zip(truth.poses, tum.poses))
        assert "no ground-truth pose: a bag holds none unless told" in open_sequence(str(out)).missing_poses()


def test_the_bag_is_read_lazily(demo_data, bag_tools, tmp_path, monkeypatch):
    """Opening keeps stamps only: reading frame 2 deserializes that frame's two images, not the bag."""
    folder = demo_data("demo_tum") / "demo" / "demo_tum"
    bag = open_sequence(str(bag_tools.write_bag(folder, tmp_path / "rec.bag")))
    seen = []
    reader = bag.bag.reader
    original = reader.deserialize
    monkeypatch.setattr(reader, "deserialize", lambda raw, msgtype: seen.append(msgtype) or original(raw, msgtype))
    bag[2]
    assert sorted(seen) == ["sensor_msgs/msg/Image", "sensor_msgs/msg/Image"]


def test_odometry_topic_is_carried_to_the_camera_by_the_static_tf(bag_tools, tmp_path):
    """topic:/odom poses are the base's: composed with /tf_static's base -> camera they are the camera's."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from clipclique.multiframe.odometry import open_odometry

    store = bag_tools.typestore(False)
    types = store.types
    rng = np.random.default_rng(1)
    extrinsic = Pose(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3))
    bases = [Pose(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3)) for _ in range(3)]
    k = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
    with Writer(tmp_path / "odom", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        add = {t: writer.add_connection(t, m, typestore=store) for t, m in [
            ("/tf_static", "tf2_msgs/msg/TFMessage"), ("/cam/image", "sensor_msgs/msg/Image"),
            ("/cam/depth", "sensor_msgs/msg/Image"), ("/cam/camera_info", "sensor_msgs/msg/CameraInfo"),
            ("/odom", "nav_msgs/msg/Odometry")]}

        def put(topic, stamp, message):
            writer.write(add[topic], int(stamp * 1e9), store.serialize_cdr(message, add[topic].msgtype))

        put("/tf_static", 0.5, types["tf2_msgs/msg/TFMessage"](
            transforms=[bag_tools.transform(store, 0.5, "base", "cam", extrinsic, False)]))
        for i, base in enumerate(bases):
            t = 1.0 + i
            put("/cam/image", t, bag_tools.image(store, t, "cam", np.zeros((12, 16, 3), np.uint8), "rgb8", False))
            put("/cam/depth", t, bag_tools.image(store, t, "cam", np.ones((12, 16), np.float32), "32FC1", False))
            put("/cam/camera_info", t, bag_tools.camera_info(store, t, "cam", (12, 16), k, False))
            stamped = bag_tools.transform(store, t + 0.005, "odom", "base", base, False)
            position, q = stamped.transform.translation, stamped.transform.rotation
            pose = types["geometry_msgs/msg/Pose"](
                position=types["geometry_msgs/msg/Point"](x=position.x, y=position.y, z=position.z), orientation=q)
            covariance = np.zeros(36)
            put("/odom", t + 0.005, types["nav_msgs/msg/Odometry"](
                header=stamped.header, child_frame_id="base",
                pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=covariance),
                twist=types["geometry_msgs/msg/TwistWithCovariance"](
                    twist=types["geometry_msgs/msg/Twist"](linear=types["geometry_msgs/msg/Vector3"](x=0, y=0, z=0),
                                                           angular=types["geometry_msgs/msg/Vector3"](x=0, y=0, z=0)),
                    covariance=covariance)))
    bag = open_sequence(str(tmp_path / "odom"))
    odometry = open_odometry("topic:/odom", 0.0, 0, bag.timestamps, bag.poses, bag)
    assert odometry.name == "topic:/odom" and bag.notes() == []
    for got, base in zip(odometry.poses, bases):
        assert np.allclose(got.matrix(), base.compose(extrinsic).matrix(), atol=1e-9)
    with pytest.raises(DatasetError, match="no nav_msgs/Odometry topic of that name"):
        open_odometry("topic:/cam/image", 0.0, 0, bag.timestamps, bag.poses, bag)
