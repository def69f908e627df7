"""The embedded demo: procedural rooms rendered into the real ScanNet and TUM RGB-D layouts.

`demo` is a ScanNet scene folder (labelled mesh, aggregation, segments, SensReader-style
frames, 2D instance images) and `demo_tum` a TUM RGB-D sequence folder (rgb/, depth/ at factor
5000, rgb.txt, depth.txt, a 100 Hz groundtruth.txt whose timestamps differ from the images', and
our object annotations). The real readers read them; nothing downstream knows they are
synthetic except through the marker file `clipclique_demo.json` (written last). Same seed, same bytes.
`demo_apartment` (ScanNet layout) and `demo_desk` (TUM layout) are scenes shaped like real data
(clipclique.sim.scenes); their marker also names the detector they are localized with.

Files beyond the official layouts (documented for users, read by our readers):
- ScanNet: `<scene>_descriptions.json`, `{"<objectId>": "a red office chair", ...}`.
- TUM: `intrinsics.txt` (`fx fy cx cy`), `annotations/objects.csv` and
  `annotations/instances/<rgb stem>.png` (see clipclique.datasets.tum).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO

import numpy as np

from clipclique.datasets.base import DEMO_MARKER, STRUCTURE_CLASSES, read_json
from clipclique.errors import DatasetError
from clipclique.perception.raycast import MeshRaycaster
from clipclique.sim.procedural import Room, Walk, make_room, make_walk
from clipclique.sim.render import sensor_depth, shade
from clipclique.sim.scenes import SCENES
from clipclique.types import Pose

GENERATOR_VERSION = 1
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class DemoSpec:
    layout: str  # "scannet" | "tum"
    seed: int
    num_frames: int = 120
    width: int = 640
    height: int = 480
    duration_s: float = 60.0  # length of the walk the frames are spread over

    def intrinsics(self) -> np.ndarray:
        """ScanNet's usual depth camera, or TUM freiburg3's, scaled to the image size."""
        fx, fy, cx, cy = (577.87, 577.87, 319.5, 239.5) if self.layout == "scannet" else (535.4, 539.2, 320.1, 247.6)
        sx, sy = self.width / 640, self.height / 480
        return np.array([[fx * sx, 0, cx * sx], [0, fy * sy, cy * sy], [0, 0, 1.0]])


    def room(self) -> Room:
        return make_room(self.seed)

    def walk(self, room: Room) -> Walk:
        return make_walk(room, self.seed, self.num_frames, self.duration_s)


@dataclass(frozen=True)
class SceneSpec(DemoSpec):
    """A scene shaped like real data (clipclique.sim.scenes); the marker records it and its detector."""

    scene: str = "apartment"  # "apartment" | "desk" | "clutter" | "sparse"
    detector: str = "gt"  # the `clipclique-loc --detector` this scene gets unless asked

    def room(self) -> Room:
        return SCENES[self.scene][0](self.seed)

    def walk(self, room: Room) -> Walk:
        return SCENES[self.scene][1](room, self.seed, self.num_frames, self.duration_s)


DEMO_SCENES: dict[str, DemoSpec] = {
    "demo": DemoSpec("scannet", seed=7),
    "demo_tum": DemoSpec("tum", seed=11),
    "demo_apartment": SceneSpec("scannet", seed=5, num_frames=60, scene="apartment", detector="gt"),
    "demo_desk": SceneSpec("tum", seed=3, num_frames=120, scene="desk", detector="simulated-yolo"),
    "demo_clutter": SceneSpec("tum", seed=17, num_frames=120, scene="clutter", detector="simulated-yolo-clutter"),
    # 900 frames at 30 Hz: stretches of 1-3.4 s at a corner with a handful of confused objects (issue 37)
    "demo_sparse": SceneSpec("tum", seed=23, num_frames=900, duration_s=30.0, scene="sparse",
                             detector="simulated-yolo-sparse"),
}


def is_generated(name: str, data_root: Path) -> bool:
    """Whether the generated scene `name` is under `<data_root>/demo/` in the current generator's version."""
    marker = Path(data_root) / "demo" / name / DEMO_MARKER
    return marker.is_file() and _marker_version(marker) == GENERATOR_VERSION


def first_use_notice(name: str, data_root: Path) -> str | None:
    """The line a command prints before it generates a scene (tens of seconds); None when there is nothing to
    generate."""
    if name not in DEMO_SCENES or is_generated(name, data_root):
        return None
    spec = DEMO_SCENES[name]
    return (f"generating the {name} scene into {Path(data_root) / 'demo' / name} (first use only: {spec.num_frames} "
            f"frames rendered on the CPU, {'about a minute' if spec.num_frames <= 120 else 'several minutes'})")


def ensure_scene(name: str, data_root: Path, progress: Progress | None = None) -> Path:
    """The generated scene `name`'s folder under `<data_root>/demo/`, generated first if absent or stale."""
    spec = DEMO_SCENES[name]
    folder = Path(data_root) / "demo" / name
    marker = folder / DEMO_MARKER
    if is_generated(name, data_root):
        return folder
    if folder.exists() and not marker.is_file():  # not ours (ours are moved into place whole): never delete it
        raise DatasetError(
            f"{folder}: exists but is not a generated demo scene (no {DEMO_MARKER}); move it away, "
            f"or point --data-root elsewhere, and the demo is generated there"
        )
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        lock = open(folder.parent / f".{name}.lock", "a")
        staging = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=folder.parent))
    except OSError as error:
        raise DatasetError(
            f"{folder.parent}: cannot write the demo scene there ({error.strerror}); point --data-root or "
            "$CLIPCLIQUE_DATA at a writable folder"
        ) from None
    try:
        with lock:
            _hold(lock)  # another process generating the same scene finishes first, and its scene is taken
            if is_generated(name, data_root):
                return folder
            generate(staging, name, spec, progress)
            staging.chmod(0o755)  # mkdtemp makes it private; the data folder is for everyone
            if folder.exists():  # an older generation of ours
                shutil.rmtree(folder)
            os.replace(staging, folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return folder


def _hold(lock: IO[str]) -> None:
    """Hold an exclusive lock on the open file until it is closed (where the platform has `fcntl`; elsewhere
    processes generating one scene at once each write it whole and the last one's stays)."""
    try:
        import fcntl
    except ImportError:
        return
    fcntl.flock(lock.fileno(), fcntl.LOCK_EX)


def scene_detector(folder: Path) -> str | None:
    """The `--detector` a generated scene is localized with unless asked: the one its marker names
    (simulated when it names none: demo, demo_tum); None for a folder the generator did not write."""
    marker = Path(folder) / DEMO_MARKER
    return str(read_json(marker).get("detector", "simulated")) if marker.is_file() else None


def _marker_version(marker: Path) -> object:
    """The generator version a demo marker records (None when unreadable: regenerate)."""
    try:
        return json.loads(marker.read_text()).get("version")
    except (ValueError, AttributeError, OSError):
        return None


def generate(folder: Path, name: str, spec: DemoSpec, progress: Progress | None = None) -> None:
    """Render the scene `name` into `folder` in the layout of `spec`; the marker file goes last."""
    if progress:
        progress(0, spec.num_frames)  # the bar shows from the start: the room, its mesh and ray caster take seconds
    room = spec.room()
    walk = spec.walk(room)
    writer = ScanNetWriter(folder, name, room) if spec.layout == "scannet" else TumWriter(folder, room, walk, spec)
    raycaster = MeshRaycaster(room.vertices, room.faces)
    face_objects, face_colors = room.face_objects(), room.face_colors()
    intrinsics = spec.intrinsics()
    writer.start(intrinsics)
    for i, (t, pose) in enumerate(zip(walk.times, walk.poses(walk.times))):
        render = raycaster.render(intrinsics, pose, (spec.height, spec.width))
        objects = np.where(render.faces >= 0, face_objects[np.maximum(render.faces, 0)], -1)
        rng = np.random.default_rng([spec.seed, i])
        rgb = shade(render, face_colors, rng)
        depth = sensor_depth(render.depth, objects, rng)
        writer.frame(i, t, rgb, depth, objects, pose)
        if progress:
            progress(i + 1, len(walk.times))
    writer.finish()
    marker = {"generator": "clipclique procedural demo (synthetic)", "version": GENERATOR_VERSION, **asdict(spec)}
    (folder / DEMO_MARKER).write_text(json.dumps(marker, indent=1) + "\n")


def _save_png(path: Path, image: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(image).save(path, compress_level=3)


def write_scannet_mesh(folder: Path, scene: str, room: Room) -> None:
    """The scan's labelled mesh, segments, aggregation and our descriptions file.

    The ply's `label` holds demo label ids (1 + the index of the category in the sorted list of
    the room's categories), not ScanNet's; readers take classes from the aggregation.
    """
    from plyfile import PlyData, PlyElement

    categories = sorted({o.category for o in room.objects})
    label_of = np.array([categories.index(o.category) + 1 for o in room.objects], dtype=np.uint16)
    vertex = np.empty(len(room.vertices),
                      dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                             ("alpha", "u1"), ("label", "u2")])
    for k, axis in enumerate("xyz"):
        vertex[axis] = room.vertices[:, k]
    for k, channel in enumerate(("red", "green", "blue")):
        vertex[channel] = room.vertex_colors[:, k]
    vertex["alpha"] = 255
    vertex["label"] = label_of[room.segment_objects[room.vertex_segments]]
    face = np.empty(len(room.faces), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = room.faces
    PlyData([PlyElement.describe(vertex, "vertex"),
             PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"})]).write(
        str(folder / f"{scene}_vh_clean_2.labels.ply")
    )
    segs_name = f"{scene}_vh_clean_2.0.010000.segs.json"
    segs = {"params": {"kThresh": "0.0001", "segMinVerts": "20", "minPoints": "750", "maxPoints": "30000",
                       "thinThresh": "0.05", "flatThresh": "0.001", "minLength": "0.02", "maxLength": "1"},
            "sceneId": scene, "segIndices": room.vertex_segments.tolist()}
    (folder / segs_name).write_text(json.dumps(segs))
    groups = [
        {"id": o.object_id, "objectId": o.object_id,
         "segments": np.flatnonzero(room.segment_objects == o.object_id).tolist(), "label": o.category}
        for o in room.objects
    ]
    aggregation = {"sceneId": f"scannet.{scene}", "appId": "Aggregator.v2", "segGroups": groups,
                   "segmentsFile": f"scannet.{segs_name}"}
    (folder / f"{scene}.aggregation.json").write_text(json.dumps(aggregation))
    descriptions = {str(o.object_id): o.description for o in room.objects if o.category not in STRUCTURE_CLASSES}
    (folder / f"{scene}_descriptions.json").write_text(json.dumps(descriptions, indent=1) + "\n")


class ScanNetWriter:
    """Files as ScanNet ships a scan plus what the official SensReader exports."""

    def __init__(self, folder: Path, scene: str, room: Room):
        self.folder, self.scene, self.room = folder, scene, room

    def start(self, intrinsics: np.ndarray) -> None:
        for sub in ("color", "depth", "pose", "intrinsic", "instance-filt"):
            (self.folder / sub).mkdir(parents=True, exist_ok=True)
        write_scannet_mesh(self.folder, self.scene, self.room)
        matrix = np.eye(4)
        matrix[:3, :3] = intrinsics
        for stem, value in (("intrinsic_depth", matrix), ("intrinsic_color", matrix), ("extrinsic_depth", np.eye(4)),
                            ("extrinsic_color", np.eye(4))):
            np.savetxt(self.folder / "intrinsic" / f"{stem}.txt", value, fmt="%f")

    def frame(self, i: int, t: float, rgb: np.ndarray, depth: np.ndarray, objects: np.ndarray, pose: Pose) -> None:
        from PIL import Image

        Image.fromarray(rgb).save(self.folder / "color" / f"{i}.jpg", quality=92)
        _save_png(self.folder / "depth" / f"{i}.png", np.round(depth * 1000).astype(np.uint16))
        np.savetxt(self.folder / "pose" / f"{i}.txt", pose.matrix(), fmt="%f")
        _save_png(self.folder / "instance-filt" / f"{i}.png", (objects + 1).astype(np.uint8))

    def finish(self) -> None:
        pass


class TumWriter:
    """Files as a TUM RGB-D sequence ships, plus our object annotations and intrinsics."""

    START = 1_700_000_000.0  # seconds, like the dataset's Unix timestamps

    def __init__(self, folder: Path, room: Room, walk: Walk, spec: DemoSpec):
        self.folder, self.room, self.walk, self.spec = folder, room, walk, spec
        self.rgb_lines: list[str] = []
        self.depth_lines: list[str] = []
        self.rng = np.random.default_rng([spec.seed, 99])
        self.annotated = np.array([o.category not in STRUCTURE_CLASSES for o in room.objects])

    def start(self, intrinsics: np.ndarray) -> None:
        for sub in ("rgb", "depth", "annotations/instances"):
            (self.folder / sub).mkdir(parents=True, exist_ok=True)
        fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
        (self.folder / "intrinsics.txt").write_text(f"# fx fy cx cy (pixels)\n{fx:.4f} {fy:.4f} {cx:.4f} {cy:.4f}\n")
        rows = ["id,class,description"] + [
            f'{o.object_id + 1},{o.category},"{o.description}"'
            for o in self.room.objects if self.annotated[o.object_id]
        ]
        (self.folder / "annotations" / "objects.csv").write_text("\n".join(rows) + "\n")

    def frame(self, i: int, t: float, rgb: np.ndarray, depth: np.ndarray, objects: np.ndarray, pose: Pose) -> None:
        # The Kinect's colour and depth streams are not synchronized: a few ms apart.
        rgb_stamp = f"{self.START + t + self.rng.uniform(0.0, 0.004):.6f}"
        depth_stamp = f"{self.START + t + self.rng.uniform(0.006, 0.014):.6f}"
        _save_png(self.folder / "rgb" / f"{rgb_stamp}.png", rgb)
        _save_png(self.folder / "depth" / f"{depth_stamp}.png",
                  np.clip(np.round(depth * 5000), 0, 65535).astype(np.uint16))
        ids = np.where((objects >= 0) & self.annotated[np.maximum(objects, 0)], objects + 1, 0)
        _save_png(self.folder / "annotations" / "instances" / f"{rgb_stamp}.png", ids.astype(np.uint16))
        self.rgb_lines.append(f"{rgb_stamp} rgb/{rgb_stamp}.png")
        self.depth_lines.append(f"{depth_stamp} depth/{depth_stamp}.png")

    def finish(self) -> None:
        from scipy.spatial.transform import Rotation

        header = "# {}\n# file: 'clipclique demo (synthetic)'\n# timestamp filename\n"
        (self.folder / "rgb.txt").write_text(header.format("color images") + "\n".join(self.rgb_lines) + "\n")
        (self.folder / "depth.txt").write_text(header.format("depth maps") + "\n".join(self.depth_lines) + "\n")
        times = np.arange(-0.2, self.spec.duration_s + 0.2, 0.01) + 0.0023  # 100 Hz motion capture, own clock phase
        lines = ["# ground truth trajectory", "# file: 'clipclique demo (synthetic)'",
                 "# timestamp tx ty tz qx qy qz qw"]
        for t, pose in zip(times, self.walk.poses(times)):
            q = Rotation.from_matrix(pose.rotation).as_quat()  # x y z w, TUM's order
            lines.append(f"{self.START + t:.4f} " + " ".join(f"{v:.4f}" for v in (*pose.translation, *q)))
        (self.folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
