"""ROS bags as sequences: a ROS 1 `.bag`, a ROS 2 bag folder (sqlite3 or mcap storage) or its `.mcap`/`.db3`.

Read through `rosbags` (pure Python, no ROS install). Opening a bag makes one pass over its colour, depth
and CameraInfo messages, one message at a time, keeping only each image's stamps and where it lies (the
bag's receive time): frames are then read from the bag when asked for, so memory stays flat in the bag's
length. `/tf` is read only for ground truth or odometry from it.

- Topics: chosen when unambiguous (one colour `sensor_msgs/Image` or `CompressedImage` topic, one depth
  topic, told apart by their first message's encoding, and the CameraInfo beside the colour topic), else
  named (`BagOptions`); `survey` says what it would pick and why (`clipclique-loc inspect`).
- Encodings: clipclique.datasets.rosimages.
- Intrinsics: CameraInfo's K (its distortion ignored, with a note when it is not zero); the colour image must
  have CameraInfo's size. Depth is assumed registered to colour (a note when its frame_id differs).
- Pairing: each colour image with the depth image nearest by `header.stamp`, within 0.02 s (TUM's rule);
  colour images without one are dropped.
- Ground truth: a TUM trajectory file (`groundtruth`), or `/tf` between two frames (`gt_frames`
  "world:camera", static transforms applied); else none. Frames are named by their colour stamp
  (`%.6f`, as TUM names its files), which `--detector file:` matches.
A bag holds no objects: maps come from elsewhere, and it has no default detector.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from clipclique.datasets.base import Instance, Sequence, intrinsics_for, resize_rgb
from clipclique.datasets.rosimages import decode_colour, decode_depth, encoding_of, is_compressed
from clipclique.datasets.rostf import TfTree, frame_id, stamp_seconds, transform_pose
from clipclique.datasets.tum import MAX_TIME_DIFF, associate, read_trajectory
from clipclique.errors import DatasetError, one_line
from clipclique.types import Frame, Pose

BAG_SUFFIXES = (".bag", ".mcap", ".db3")
NO_DETECTOR = "none"  # a bag's default detector: none (the run asks for --detector)
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_TYPE = "tf2_msgs/msg/TFMessage"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
TF_TOPICS = {"/tf": False, "/tf_static": True}  # topic -> static
DEPTH_IMAGE_ENCODINGS = ("32FC1", "16UC1", "mono16")


def is_bag(path: Path) -> bool:
    """A ROS 1 bag or ROS 2 storage file by its suffix, or a ROS 2 bag folder (it holds metadata.yaml)."""
    path = Path(path)
    return (path.is_file() and path.suffix in BAG_SUFFIXES) or (path.is_dir() and (path / "metadata.yaml").is_file())


def require_bag(path: Path) -> Path:
    """`path`, or a DatasetError saying what a bag is (the commands that take only a bag: inspect, convert)."""
    if not is_bag(path):
        raise DatasetError(f"{path}: not a ROS bag (a .bag, .mcap or .db3 file, or a folder holding metadata.yaml)")
    return Path(path)


@dataclass
class BagOptions:
    """What a user may tell the bag reader (`clipclique-loc run` options of the same names)."""

    rgb_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    depth_scale: float | None = None  # metres per stored depth unit, instead of the encoding's
    groundtruth: Path | None = None  # a TUM trajectory file
    gt_frames: str | None = None  # "WORLD:CAMERA": ground truth from /tf

    def image_options(self) -> tuple[str | None, str | None, str | None, float | None]:
        """The options that choose the images read (topics, depth unit); the ground truth changes none of them."""
        return self.rgb_topic, self.depth_topic, self.camera_info_topic, self.depth_scale


@dataclass
class Topic:
    """One topic of a bag as `survey` reports it."""

    name: str
    msgtype: str
    count: int
    rate_hz: float
    encoding: str = ""  # first message's encoding (images) ...
    frame_id: str = ""  # ... and its header.frame_id
    role: str = ""  # "colour", "depth", "camera_info", "tf", "odometry" or ""


@dataclass
class Survey:
    """A bag's topics and the choice the reader makes (or why it cannot)."""

    path: Path
    duration_s: float
    topics: list[Topic]
    chosen: dict[str, str] = field(default_factory=dict)  # role -> topic
    reasons: list[str] = field(default_factory=list)
    problem: str | None = None  # why no sequence can be read without naming a topic


class BagReader:
    """An open bag; one `rosbags` reader per thread (sqlite3 connections stay in the thread that made them)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self._local = threading.local()
        self.reader  # noqa: B018  (open now: a bad bag fails here, in one line)

    @property
    def reader(self) -> Any:
        reader = getattr(self._local, "reader", None)
        if reader is None:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore

            try:
                reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
                reader.open()
            except Exception as error:  # rosbags raises many kinds; every one is an unreadable bag
                raise DatasetError(
                    f"{self.path}: not a readable ROS bag ({one_line(error) or type(error).__name__})"
                ) from None
            self._local.reader = reader
        return reader

    def messages(
        self, topics: list[str], start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[str, int, object]]:
        """(topic, receive time ns, message) of `topics` in time order, deserialized one at a time."""
        reader = self.reader
        connections = [c for c in reader.connections if c.topic in topics]
        if not connections:
            return
        try:
            for connection, time_ns, raw in reader.messages(connections=connections, start=start, stop=stop):
                yield connection.topic, time_ns, reader.deserialize(raw, connection.msgtype)
        except DatasetError:
            raise
        except Exception as error:
            raise DatasetError(
                f"{self.path}: unreadable message ({one_line(error) or type(error).__name__}); "
                "the bag may be truncated or damaged"
            ) from None

    def first(self, topic: str) -> object | None:
        return next((message for _, _, message in self.messages([topic])), None)

    def topics(self) -> dict[str, tuple[str, int]]:
        """Topic -> (message type, count)."""
        return {name: (info.msgtype or "?", int(info.msgcount)) for name, info in self.reader.topics.items()}

    def duration_s(self) -> float:
        reader = self.reader
        return max(reader.duration, 0) * 1e-9 if reader.message_count else 0.0


def _role(msgtype: str, first: object | None) -> str:
    if msgtype in IMAGE_TYPES:
        if first is None:
            return ""
        encoding = encoding_of(first)
        return (
            "depth"
            if ("compressedDepth" in encoding or (not is_compressed(first) and encoding in DEPTH_IMAGE_ENCODINGS))
            else "colour"
        )
    return {CAMERA_INFO: "camera_info", TF_TYPE: "tf", ODOMETRY_TYPE: "odometry"}.get(msgtype, "")


def survey(bag: BagReader, options: BagOptions = BagOptions()) -> Survey:
    """Every topic with type, count, rate and (images) encoding, and the colour/depth/CameraInfo choice."""
    duration = bag.duration_s()
    topics = []
    for name, (msgtype, count) in sorted(bag.topics().items()):
        first = bag.first(name) if msgtype in IMAGE_TYPES and count else None
        header = getattr(first, "header", None)
        topics.append(
            Topic(
                name,
                msgtype,
                count,
                count / duration if duration > 0 else 0.0,
                encoding_of(first) if first is not None else "",
                frame_id(header.frame_id) if header is not None else "",
                _role(msgtype, first),
            )
        )
    found = Survey(bag.path, duration, topics)
    try:
        _choose(found, options)
    except DatasetError as error:
        found.problem = str(error)
    return found


def _choose(found: Survey, options: BagOptions) -> None:
    """Fill `found.chosen` and its reasons; a DatasetError naming the bag and the option when it cannot."""
    by_name = {topic.name: topic for topic in found.topics}
    given = {
        "colour": (options.rgb_topic, "--rgb-topic"),
        "depth": (options.depth_topic, "--depth-topic"),
        "camera_info": (options.camera_info_topic, "--camera-info-topic"),
    }
    for role, (name, flag) in given.items():
        if name is None:
            continue
        wanted = (CAMERA_INFO,) if role == "camera_info" else IMAGE_TYPES
        if name not in by_name:
            raise DatasetError(f"{found.path}: {flag} {name}: no such topic (topics: {', '.join(by_name) or 'none'})")
        if by_name[name].msgtype not in wanted:
            raise DatasetError(f"{found.path}: {flag} {name} is a {by_name[name].msgtype}, not a {' or '.join(wanted)}")
        found.chosen[role] = name
        found.reasons.append(f"{role}: {name} ({flag})")
    for role, flag in (("colour", "--rgb-topic"), ("depth", "--depth-topic")):
        if role in found.chosen:
            continue
        candidates = [topic.name for topic in found.topics if topic.role == role]
        if len(candidates) != 1:
            kind = "colour Image or CompressedImage" if role == "colour" else "depth (32FC1, 16UC1 or compressedDepth)"
            listed = f"{len(candidates)} {kind} topics ({', '.join(candidates)})" if candidates else f"no {kind} topic"
            raise DatasetError(f"{found.path}: {listed}; name the one to read with {flag} TOPIC")
        found.chosen[role] = candidates[0]
        found.reasons.append(f"{role}: {candidates[0]} (the only {role} image topic)")
    if "camera_info" not in found.chosen:
        infos = [topic.name for topic in found.topics if topic.role == "camera_info"]
        beside = f"{found.chosen['colour'].rsplit('/', 1)[0]}/camera_info"
        if beside in infos:
            found.chosen["camera_info"] = beside
            found.reasons.append(f"camera_info: {beside} (beside the colour topic)")
        elif len(infos) == 1:
            found.chosen["camera_info"] = infos[0]
            found.reasons.append(f"camera_info: {infos[0]} (the only CameraInfo topic)")
        elif not infos:
            raise DatasetError(
                f"{found.path}: no sensor_msgs/CameraInfo topic: the camera's intrinsics are unknown "
                "(record the colour camera's camera_info with the images)"
            )
        else:
            raise DatasetError(
                f"{found.path}: {len(infos)} CameraInfo topics ({', '.join(infos)}) and none beside "
                f"{found.chosen['colour']}; name one with --camera-info-topic TOPIC"
            )


@dataclass
class Stamped:
    """Where one image lies in the bag: its receive time (to seek) and its header stamp (to pair and match)."""

    time_ns: int
    stamp: float


class BagSequence(Sequence):
    kind = "rosbag"
    default_detector = NO_DETECTOR
    synthetic = False

    @staticmethod
    def recognizes(folder: Path) -> bool:
        return is_bag(folder)

    def __init__(self, path: Path, options: BagOptions | None = None):
        self.root = Path(path)
        self.name = self.root.name if self.root.is_dir() else self.root.stem
        self.options = options or BagOptions()
        if self.options.depth_scale is not None and not (
            np.isfinite(self.options.depth_scale) and self.options.depth_scale > 0
        ):
            raise DatasetError(
                f"{self.root}: --depth-scale {self.options.depth_scale:g}: metres per depth unit must be a "
                "positive number"
            )
        self.bag = BagReader(self.root)
        self.survey = survey(self.bag, self.options)
        if self.survey.problem:
            raise DatasetError(self.survey.problem)
        self.topics = self.survey.chosen
        self._notes: list[str] = []
        colour, depth, info = self._index()
        self.intrinsics, self.distortion = self._camera(info)
        pairs = associate(np.array([c.stamp for c in colour]), np.array([d.stamp for d in depth]))
        keep = np.flatnonzero(pairs >= 0)
        if not len(keep):
            raise DatasetError(
                f"{self.root}: no image of {self.topics['colour']} ({len(colour)}) has a depth image of "
                f"{self.topics['depth']} ({len(depth)}) within {MAX_TIME_DIFF} s of its header.stamp"
            )
        self.colour = [colour[k] for k in keep]
        self.depth = [depth[pairs[k]] for k in keep]
        self.timestamps = np.array([c.stamp for c in self.colour])
        self.poses = self._ground_truth()

    def _index(self) -> tuple[list[Stamped], list[Stamped], object]:
        """One pass over the chosen topics: image stamps and the first CameraInfo (/tf waits until asked: `tf`)."""
        colour: list[Stamped] = []
        depth: list[Stamped] = []
        info = None
        frames: dict[str, str] = {}
        wanted = [self.topics["colour"], self.topics["depth"], self.topics["camera_info"]]
        for topic, time_ns, message in self.bag.messages(wanted):
            if topic == self.topics["camera_info"]:
                info = info or message
            else:
                (colour if topic == self.topics["colour"] else depth).append(
                    Stamped(time_ns, stamp_seconds(message.header.stamp))
                )
                frames.setdefault(topic, frame_id(message.header.frame_id))
        if info is None:
            raise DatasetError(f"{self.root}: {self.topics['camera_info']} holds no CameraInfo message")
        colour_frame, depth_frame = frames.get(self.topics["colour"]), frames.get(self.topics["depth"])
        if colour_frame and depth_frame and colour_frame != depth_frame:
            self._notes.append(
                f"depth ({self.topics['depth']}, frame {depth_frame}) is read as registered to colour "
                f"({self.topics['colour']}, frame {colour_frame}); if it is not, record the aligned "
                "depth (RealSense: aligned_depth_to_color)"
            )
        self.colour_frame = colour_frame or ""
        return colour, depth, info

    def _camera(self, info: object) -> tuple[np.ndarray, np.ndarray]:
        """(K, distortion) of a CameraInfo (ROS 1 names K and D, ROS 2 k and d)."""
        where = f"{self.root}, {self.topics['camera_info']}"
        k = np.asarray(getattr(info, "k", getattr(info, "K", ())), np.float64).reshape(-1)
        d = np.asarray(getattr(info, "d", getattr(info, "D", ())), np.float64).reshape(-1)
        if k.size != 9 or not np.isfinite(k).all() or k[0] <= 0 or k[4] <= 0 or k[2] <= 0 or k[5] <= 0:
            raise DatasetError(f"{where}: K {k.tolist()} is not a camera matrix (fx, fy, cx, cy > 0)")
        self.info_size = (int(info.height), int(info.width))
        if d.size and np.any(np.abs(d) > 1e-9):
            self._notes.append(
                f"{self.topics['camera_info']}: the images are distorted ({info.distortion_model} "
                f"{np.round(d, 4).tolist()}); the distortion is ignored"
            )
        return k.reshape(3, 3), d

    def _ground_truth(self) -> list[Pose | None]:
        if self.options.groundtruth is not None and self.options.gt_frames is not None:
            raise DatasetError("--groundtruth and --gt-frames both give ground truth: pass one")
        if self.options.groundtruth is not None:
            times, poses = read_trajectory(Path(self.options.groundtruth))
            nearest = associate(self.timestamps, times)
            return [poses[k] if k >= 0 else None for k in nearest]
        if self.options.gt_frames is not None:
            return self.tf_poses(self.options.gt_frames, "--gt-frames ")
        return [None] * len(self.colour)

    @cached_property
    def tf(self) -> TfTree:
        """/tf and /tf_static, read in one pass of their own when ground truth or odometry asks (a 100 Hz /tf
        holds more messages than the images: a run without them never reads it)."""
        tree = TfTree()
        for topic, _, message in self.bag.messages(list(TF_TOPICS)):
            tree.add(message, TF_TOPICS[topic], f"{self.root}, {topic}")
        return tree

    def tf_poses(self, spec: str, flag: str) -> list[Pose | None]:
        """Each frame's pose of CHILD in PARENT (`spec` "PARENT:CHILD") from /tf, static transforms applied; errors
        name `flag` + `spec` ("--gt-frames world:camera")."""
        parent, sep, child = spec.partition(":")
        if not sep or not parent or not child:
            raise DatasetError(f"{flag}{spec!r}: expected PARENT:CHILD, two tf frame names (e.g. world:camera)")
        try:
            return self.tf.poses(parent, child, self.timestamps, MAX_TIME_DIFF)
        except DatasetError as error:
            raise DatasetError(f"{self.root}: {flag}{spec}: {error}") from None

    def odometry_track(self, topic: str) -> tuple[np.ndarray, list[Pose]]:
        """(stamps, camera poses) of a nav_msgs/Odometry topic; its child frame is carried to the colour
        camera by /tf's static transforms when they connect them (else taken as the camera's, with a note)."""
        if self.bag.topics().get(topic, ("",))[0] != ODOMETRY_TYPE:
            raise DatasetError(f"{self.root}: --odometry topic:{topic}: no nav_msgs/Odometry topic of that name")
        times, poses, child = [], [], ""
        for _, _, message in self.bag.messages([topic]):
            times.append(stamp_seconds(message.header.stamp))
            poses.append(transform_pose(message.pose.pose))
            child = child or frame_id(message.child_frame_id)
        try:
            extrinsic = (
                self.tf.poses(child, self.colour_frame, np.zeros(1), np.inf)[0] if child and self.colour_frame else None
            )
        except DatasetError:
            extrinsic = None
        if extrinsic is None:
            self._notes.append(
                f"--odometry topic:{topic}: /tf does not connect its frame {child or '?'} to the colour "
                f"camera's {self.colour_frame or '?'}; its poses are taken as the camera's"
            )
        else:
            poses = [pose.compose(extrinsic) for pose in poses]
        return np.array(times), poses

    def notes(self) -> list[str]:
        return list(self._notes)

    def missing_poses(self) -> str | None:
        missing = sum(pose is None for pose in self.poses)
        if not missing:
            return None
        if self.options.groundtruth is None and self.options.gt_frames is None:
            return (
                f"{missing} of {len(self)} frames have no ground-truth pose: a bag holds none unless told "
                "(--groundtruth FILE.txt or --gt-frames WORLD:CAMERA)"
            )
        source = self.options.groundtruth or f"/tf {self.options.gt_frames}"
        return f"{missing} of {len(self)} frames have no ground-truth pose: {source} has none within {MAX_TIME_DIFF} s"

    def __len__(self) -> int:
        return len(self.colour)

    def frame_name(self, i: int) -> str:
        """Frame `i`'s name: its colour stamp as TUM names its files (`1305031102.175304`)."""
        return f"{self.colour[i].stamp:.6f}"

    def trajectory(self) -> tuple[np.ndarray, list[Pose | None]]:
        return self.timestamps.copy(), list(self.poses)

    def _message(self, topic: str, where: Stamped) -> object:
        for _, _, message in self.bag.messages([topic], where.time_ns, where.time_ns + 1):
            if stamp_seconds(message.header.stamp) == where.stamp:
                return message
        raise DatasetError(f"{self.root}: the {topic} message at {where.stamp:.6f} s is gone (the bag changed?)")

    def __getitem__(self, i: int) -> Frame:
        i = self._check_index(i)
        name = self.frame_name(i)
        rgb_msg = self._message(self.topics["colour"], self.colour[i])
        rgb = decode_colour(rgb_msg, f"{self.root}, {self.topics['colour']} at {name}")
        if self.info_size != (0, 0) and rgb.shape[:2] != self.info_size:
            raise DatasetError(
                f"{self.root}, {self.topics['colour']} at {name}: image is {rgb.shape[1]} x {rgb.shape[0]}, "
                f"its CameraInfo ({self.topics['camera_info']}) {self.info_size[1]} x {self.info_size[0]}"
            )
        depth_msg = self._message(self.topics["depth"], self.depth[i])
        where = f"{self.root}, {self.topics['depth']} at {self.depth[i].stamp:.6f}"
        depth = decode_depth(depth_msg, where, self.options.depth_scale)
        del depth_msg, rgb_msg
        intrinsics = intrinsics_for(self.intrinsics, depth.shape, Path(where), f"{self.topics['camera_info']}'s K")
        return Frame(
            i,
            float(self.timestamps[i]),
            resize_rgb(rgb, depth.shape),
            depth,
            intrinsics,
            self.poses[i],
            None,
            name=name,
        )

    def instances(self) -> list[Instance]:
        return []

    def object_classes(self) -> dict[int, str]:
        return {}

    def descriptions(self) -> dict[int, str]:
        return {}
