"""Write a TUM RGB-D folder as a ROS bag, for trying and testing the bag reader without a robot.

Two layouts:
- `tum`: TUM's published one: `/camera/rgb/image_color` (rgb8), `/camera/depth/image` (32FC1 metres,
  NaN where missing), `/camera/rgb/camera_info`, and `/tf`: world -> kinect from groundtruth.txt, with a
  static kinect -> openni_rgb_optical_frame (on /tf_static), so that `--gt-frames
  world:openni_rgb_optical_frame` is the ground truth;
- `realsense`: a RealSense driver's: `/camera/color/image_raw/compressed` (JPEG),
  `/camera/aligned_depth_to_color/image_raw` (16UC1 millimetres), `/camera/color/camera_info`, same /tf.
Storage: a ROS 1 `.bag`, or a ROS 2 folder in mcap or sqlite3 (`--storage`). Messages are written in time
order one at a time, so a long sequence never sits in memory; `--repeat N` writes the sequence N times
over (later copies shifted in time), for memory benchmarks. A bag holds no annotations; for a generated
scene, `--detections FILE.json --map MAP` also writes what its simulated detector sees in each frame of the
folder (COCO results in MAP's classes, their images.json beside), for
`clipclique-loc run BAG --detector file:FILE.json`.

    python tools/tum_to_bag.py data/demo/demo_tum demo_tum.bag --map outputs/maps/demo_tum.map.npz \
        --detections demo_tum.detections.json
    python tools/tum_to_bag.py data/demo/demo_tum demo_tum_realsense --storage mcap --layout realsense
"""

from __future__ import annotations

import argparse
import io
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from clipclique.datasets.tum import DEPTH_FACTOR, TumSequence, read_file_list, read_trajectory
from clipclique.types import Pose

LAYOUTS = {
    "tum": {
        "colour": "/camera/rgb/image_color",
        "depth": "/camera/depth/image",
        "info": "/camera/rgb/camera_info",
        "frame": "openni_rgb_optical_frame",
    },
    "realsense": {
        "colour": "/camera/color/image_raw/compressed",
        "depth": "/camera/aligned_depth_to_color/image_raw",
        "info": "/camera/color/camera_info",
        "frame": "camera_color_optical_frame",
    },
}
WORLD, BODY = "world", "kinect"
# The camera's optical frame on the body: x right, y down, z forward, with the body's x forward (REP 103).
OPTICAL = Pose(Rotation.from_euler("ZYX", [-90, 0, -90], degrees=True).as_matrix(), np.array([0.05, -0.02, 0.1]))
STORAGES = ("ros1", "mcap", "sqlite3")


def typestore(ros1: bool):
    """The message types: ROS 1 Noetic (plus tf2_msgs/TFMessage, which it lacks) or ROS 2 Humble."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    return store


def header(store, stamp: float, frame: str, ros1: bool):
    types = store.types
    sec = int(np.floor(stamp))
    time = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
    fields = {"seq": 0} if ros1 else {}
    return types["std_msgs/msg/Header"](**fields, stamp=time, frame_id=frame)


def transform(store, stamp: float, parent: str, child: str, pose: Pose, ros1: bool):
    types = store.types
    q = Rotation.from_matrix(pose.rotation).as_quat()
    return types["geometry_msgs/msg/TransformStamped"](
        header=header(store, stamp, parent, ros1),
        child_frame_id=child,
        transform=types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](
                x=float(pose.translation[0]), y=float(pose.translation[1]), z=float(pose.translation[2])
            ),
            rotation=types["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        ),
    )


def camera_info(store, stamp: float, frame: str, size: tuple[int, int], k: np.ndarray, ros1: bool):
    height, width = size
    names = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
    p = np.hstack([k, np.zeros((3, 1))]).reshape(-1)
    values = (np.zeros(5), k.reshape(-1).astype(np.float64), np.eye(3).reshape(-1), p)
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return store.types["sensor_msgs/msg/CameraInfo"](
        header=header(store, stamp, frame, ros1),
        height=height,
        width=width,
        distortion_model="plumb_bob",
        **dict(zip(names, values)),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def image(store, stamp: float, frame: str, pixels: np.ndarray, encoding: str, ros1: bool):
    height, width = pixels.shape[:2]
    data = np.ascontiguousarray(pixels).view(np.uint8).reshape(-1)
    return store.types["sensor_msgs/msg/Image"](
        header=header(store, stamp, frame, ros1),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=pixels.dtype.itemsize * int(np.prod(pixels.shape[1:])),
        data=data,
    )


def compressed(store, stamp: float, frame: str, pixels: np.ndarray, ros1: bool):
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, "JPEG", quality=95)
    return store.types["sensor_msgs/msg/CompressedImage"](
        header=header(store, stamp, frame, ros1), format="jpeg", data=np.frombuffer(buffer.getvalue(), np.uint8)
    )


def events(folder: Path, layout: str, repeat: int) -> Iterator[tuple[float, str, str, object]]:
    """(time, topic, message type, maker of the message) of the whole bag, in time order."""
    names = LAYOUTS[layout]
    rgb_times, rgb_files = read_file_list(folder / "rgb.txt")
    depth_times, depth_files = read_file_list(folder / "depth.txt")
    gt_times, gt_poses = (
        read_trajectory(folder / "groundtruth.txt") if (folder / "groundtruth.txt").exists() else ([], [])
    )
    span = max([*rgb_times, *depth_times, *gt_times]) - min([*rgb_times, *depth_times, *gt_times]) + 1.0
    found = [(float(min(rgb_times)) - 1e-3, "/tf_static", "tf", ("static", OPTICAL))]
    for copy in range(repeat):
        shift = copy * span
        found += [(t + shift, names["colour"], "colour", folder / f) for t, f in zip(rgb_times, rgb_files)]
        found += [(t + shift, names["info"], "info", folder / f) for t, f in zip(rgb_times, rgb_files)]
        found += [(t + shift, names["depth"], "depth", folder / f) for t, f in zip(depth_times, depth_files)]
        found += [
            (t + shift, "/tf", "tf", ("dynamic", pose.compose(OPTICAL.inverse())))
            for t, pose in zip(gt_times, gt_poses)
        ]
    found.sort(key=lambda event: event[0])
    return iter(found)


def write_bag(folder: Path, out: Path, storage: str = "ros1", layout: str = "tum", repeat: int = 1) -> Path:
    """Write the TUM folder `folder` as a bag at `out` (a .bag file for ros1, else a ROS 2 folder); `out`."""
    ros1 = storage == "ros1"
    store = typestore(ros1)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    names = LAYOUTS[layout]
    types = {
        "colour": "sensor_msgs/msg/CompressedImage" if layout == "realsense" else "sensor_msgs/msg/Image",
        "depth": "sensor_msgs/msg/Image",
        "info": "sensor_msgs/msg/CameraInfo",
        "tf": "tf2_msgs/msg/TFMessage",
    }
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(out)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(
            out, version=9, storage_plugin=StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        )
    k = TumSequence(Path(folder)).intrinsics
    with writer:
        connections: dict[str, object] = {}
        for stamp, topic, kind, payload in events(Path(folder), layout, repeat):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, types[kind], typestore=store)
            if kind == "tf":
                which, pose = payload
                parent, child = (BODY, names["frame"]) if which == "static" else (WORLD, BODY)
                message = store.types["tf2_msgs/msg/TFMessage"](
                    transforms=[transform(store, stamp, parent, child, pose, ros1)]
                )
            elif kind == "depth":
                metres = np.asarray(Image.open(payload), np.uint16).astype(np.float32) / np.float32(DEPTH_FACTOR)
                if layout == "realsense":
                    message = image(
                        store, stamp, names["frame"], np.round(metres * 1000).astype(np.uint16), "16UC1", ros1
                    )
                else:
                    message = image(
                        store,
                        stamp,
                        names["frame"],
                        np.where(metres > 0, metres, np.nan).astype(np.float32),
                        "32FC1",
                        ros1,
                    )
            else:
                rgb = np.asarray(Image.open(payload).convert("RGB"))
                if kind == "info":
                    message = camera_info(store, stamp, names["frame"], rgb.shape[:2], k, ros1)
                elif layout == "realsense":
                    message = compressed(store, stamp, names["frame"], rgb, ros1)
                else:
                    message = image(store, stamp, names["frame"], rgb, "rgb8", ros1)
            serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
            writer.write(connections[topic], int(round(stamp * 1e9)), serialize(message, types[kind]))
    return out


def write_detections(folder: Path, map_path: Path, out: Path) -> Path:
    """What the folder's own (simulated) detector sees in each of its frames, in the map's classes, as COCO
    results `out` with their image list images.json beside it; `out`."""
    from clipclique.backends import make_detector
    from clipclique.interop.coco import reported_classes
    from clipclique.interop.detections import CocoRecorder
    from clipclique.io.mapfile import load_map
    from clipclique.perception.yolo import coco_to_vocabulary
    from clipclique.resolve import default_detector, open_scene

    sequence, names = open_scene(str(folder)), load_map(map_path).class_names
    detector = make_detector(default_detector(sequence), sequence.object_classes(), names)
    recorder = CocoRecorder(names, reported_classes(coco_to_vocabulary(names), names))
    for frame in sequence:
        recorder.add(frame, detector.detect(frame))
    out.parent.mkdir(parents=True, exist_ok=True)
    recorder.write(out, out.parent / "images.json")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="a TUM RGB-D folder (rgb.txt, depth.txt, groundtruth.txt)")
    parser.add_argument("out", type=Path, help="the bag to write: NAME.bag (ros1) or a ROS 2 bag folder")
    parser.add_argument("--storage", choices=STORAGES, default="ros1")
    parser.add_argument("--layout", choices=tuple(LAYOUTS), default="tum")
    parser.add_argument("--repeat", type=int, default=1, help="write the sequence N times over")
    parser.add_argument("--detections", type=Path, help="also write the folder's simulated detections here ...")
    parser.add_argument("--map", type=Path, help="... in the classes of this map (needed with --detections)")
    args = parser.parse_args()
    if args.out.exists():
        sys.exit(f"tum_to_bag: {args.out} exists; remove it or choose another name")
    print(write_bag(args.folder, args.out, args.storage, args.layout, args.repeat))
    if args.detections:
        if args.map is None:
            sys.exit("tum_to_bag: --detections needs --map MAP.map.npz (the classes to write them in)")
        print(write_detections(args.folder, args.map, args.detections))


if __name__ == "__main__":
    main()
