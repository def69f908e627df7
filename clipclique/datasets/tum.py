"""TUM RGB-D sequences, as the benchmark ships them, plus our object annotations.

Read from `rgbd_dataset_freiburgN_.../`:
- `rgb.txt`, `depth.txt`: `timestamp filename` lines (`#` comments);
- `groundtruth.txt`: `timestamp tx ty tz qx qy qz qw` lines, read strictly (8 numbers or an
  error naming the file and line); camera-to-world in the motion-capture frame;
- `rgb/*.png`, `depth/*.png` (uint16, metres x 5000).
Each colour image is paired with the depth image and the ground-truth pose nearest in time,
when within MAX_TIME_DIFF seconds (frames without a depth image are dropped, frames without a
pose get `pose=None`). Intrinsics come from the sequence name (freiburg1/2/3, as published,
distortion ignored) or from `intrinsics.txt` (ours: one line `fx fy cx cy`).

Object annotations (ours, for building maps and as ground-truth detections):
- `annotations/objects.csv`: header `id,class,description`; id an integer >= 1, class a
  class name (e.g. a COCO name such as `chair`), description free text ("a red office chair");
- `annotations/instances/<rgb stem>.png`: uint16 (or 8-bit) image the size of the depth
  image, each pixel the id of the object it shows, 0 = none. Annotate any subset of frames.
"""

from __future__ import annotations

import csv
import io
import math
import re
from functools import cached_property
from pathlib import Path

import numpy as np

from clipclique.datasets.base import (
    Instance,
    Sequence,
    description_template,
    intrinsics_for,
    is_demo,
    is_structure,
    read_depth,
    read_image,
    read_instance_ids,
    resize_rgb,
)
from clipclique.errors import ClipcliqueError, DatasetError
from clipclique.io import safeio
from clipclique.perception.depth import backproject
from clipclique.types import Frame, Pose

DEPTH_FACTOR = 5000.0
MAX_TIME_DIFF = 0.02  # seconds, as TUM's associate.py
# Published calibrations (fx, fy, cx, cy) of the three Kinects, for 640 x 480 images.
INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}
MAX_OBJECT_ID = 65535  # annotation ids are pixel values of 16-bit images
ANNOTATION_STRIDE = 2  # map building back-projects every 2nd pixel row and column of a mask


def _data_lines(path: Path):
    """(line number, stripped text) of the non-comment, non-empty lines of a TUM text file (strict UTF-8)."""
    text = safeio.read_text(path, "TUM text file", DatasetError)
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield number, line


def read_file_list(path: Path) -> tuple[np.ndarray, list[str]]:
    """Timestamps and file names of an rgb.txt / depth.txt."""
    times, names = [], []
    for number, line in _data_lines(path):
        parts = line.split()
        try:
            if len(parts) != 2:
                raise ValueError
            times.append(float(parts[0]))
        except ValueError:
            raise DatasetError(f"{path}, line {number}: expected 'timestamp filename', got {line!r}") from None
        if Path(parts[1]).is_absolute() or ".." in Path(parts[1]).parts:
            raise DatasetError(f"{path}, line {number}: {parts[1]!r} is not a path inside the sequence folder")
        names.append(parts[1])
    return np.array(times, dtype=np.float64), names


def read_trajectory(path: Path) -> tuple[np.ndarray, list[Pose]]:
    """Timestamps and camera-to-world poses of a TUM trajectory file (8 columns per line)."""
    from scipy.spatial.transform import Rotation

    rows = []
    for number, line in _data_lines(path):
        parts = line.replace(",", " ").split()
        try:
            if len(parts) != 8:
                raise ValueError
            row = [float(p) for p in parts]
        except ValueError:
            raise DatasetError(f"{path}, line {number}: expected 8 numbers 'timestamp tx ty tz qx "
                               f"qy qz qw', got {line!r}") from None
        if not np.isfinite(row).all() or np.linalg.norm(row[4:]) < 1e-6:
            raise DatasetError(f"{path}, line {number}: not a finite pose with a unit quaternion: {line!r}")
        rows.append(row)
    if not rows:
        return np.zeros(0), []
    table = np.array(rows)
    rotations = Rotation.from_quat(table[:, 4:]).as_matrix()  # scipy normalizes; order x y z w as TUM
    return table[:, 0], [Pose(r, t) for r, t in zip(rotations, table[:, 1:4])]


def tum_line(timestamp: float, pose: Pose) -> str:
    """One line of a TUM trajectory file, as `read_trajectory` reads it back (to the micrometre)."""
    from scipy.spatial.transform import Rotation

    quaternion = Rotation.from_matrix(pose.rotation).as_quat()  # x, y, z, w
    return " ".join(f"{v:.6f}" for v in (timestamp, *pose.translation, *quaternion))


def associate(times: np.ndarray, candidates: np.ndarray, max_diff: float = MAX_TIME_DIFF) -> np.ndarray:
    """Index of the candidate nearest in time to each of `times`, or -1 when none is within max_diff."""
    if len(candidates) == 0:
        return np.full(len(times), -1)
    order = np.argsort(candidates)
    sorted_c = candidates[order]
    right = (np.clip(np.searchsorted(sorted_c, times), 1, len(sorted_c) - 1) if len(sorted_c) > 1
             else np.zeros(len(times), int))
    left = np.maximum(right - 1, 0)
    nearest = np.where(np.abs(sorted_c[left] - times) <= np.abs(sorted_c[right] - times), left, right)
    return np.where(np.abs(sorted_c[nearest] - times) <= max_diff, order[nearest], -1)


def read_objects_table(path: Path, max_id: int = MAX_OBJECT_ID,
                       error: type[ClipcliqueError] = DatasetError) -> dict[int, tuple[str, str]]:
    """Object id -> (class, description) of an `id,class,description` CSV (the TUM annotations'
    objects.csv, and the classes of an imported SLAM map); an empty description becomes the template."""
    objects: dict[int, tuple[str, str]] = {}
    reader = csv.DictReader(io.StringIO(safeio.read_text(path, "objects table", error), newline=""))
    missing = {"id", "class", "description"} - set(reader.fieldnames or ())
    if missing:
        raise error(f"{path}: header must be 'id,class,description' (missing {', '.join(sorted(missing))})")
    for row in reader:
        where = f"{path}, line {reader.line_num}"
        try:
            object_id = int(row["id"])
        except (TypeError, ValueError):
            raise error(f"{where}: id {row['id']!r} is not an integer") from None
        if not 1 <= object_id <= max_id:
            raise error(f"{where}: id {object_id} outside 1..{max_id} (the instance images are 16-bit)")
        if object_id in objects:
            raise error(f"{where}: id {object_id} appears twice")
        name = safeio.check_text(row["class"] or "", f"{where}: class", error).strip()
        if not name:
            raise error(f"{where}: class is empty")
        description = safeio.check_text(row["description"] or "", f"{where}: description", error).strip()
        objects[object_id] = (name, description or description_template(name))
    return objects


class TumSequence(Sequence):
    kind = "tum"
    default_detector = "annotations"

    @staticmethod
    def recognizes(folder: Path) -> bool:
        return (folder / "rgb.txt").exists()

    def __init__(self, folder: Path):
        self.root = Path(folder)
        self.name = self.root.name
        self.synthetic = is_demo(self.root)
        rgb_times, rgb_files = read_file_list(self.root / "rgb.txt")
        depth_times, depth_files = read_file_list(self.root / "depth.txt")
        for listed, path in ((rgb_times, "rgb.txt"), (depth_times, "depth.txt")):
            if not len(listed):
                raise DatasetError(f"{self.root / path}: lists no images (expected 'timestamp filename' lines)")
        gt_path = self.root / "groundtruth.txt"
        gt_times, gt_poses = read_trajectory(gt_path) if gt_path.exists() else (np.zeros(0), [])
        to_depth = associate(rgb_times, depth_times)
        to_pose = associate(rgb_times, gt_times)
        keep = np.flatnonzero(to_depth >= 0)
        if not len(keep):
            raise DatasetError(f"{self.root}: no colour image of rgb.txt has a depth image of depth.txt within "
                               f"{MAX_TIME_DIFF} s")
        self.timestamps = rgb_times[keep]
        self.rgb_files = [rgb_files[k] for k in keep]
        self.depth_files = [depth_files[to_depth[k]] for k in keep]
        self.poses = [gt_poses[to_pose[k]] if to_pose[k] >= 0 else None for k in keep]
        self.pose_times = np.sort(gt_times)
        self.intrinsics = self._intrinsics()

    def missing_poses(self) -> str | None:
        missing = sum(pose is None for pose in self.poses)
        if not missing:
            return None
        path = self.root / "groundtruth.txt"
        if not path.exists():
            why = f"there is no {path}"
        elif not len(self.pose_times):
            why = f"{path} holds no pose"
        else:
            why = f"{path} has no pose within {MAX_TIME_DIFF} s of their colour image"
            spacing = float(np.median(np.diff(self.pose_times))) if len(self.pose_times) > 1 else math.inf
            if spacing > MAX_TIME_DIFF:
                why += (f" (its poses are {spacing:.3g} s apart: record poses at {1 / MAX_TIME_DIFF:g} Hz or more, or "
                        "write one per colour image with its timestamp)")
            elif self.timestamps[0] < self.pose_times[0] or self.timestamps[-1] > self.pose_times[-1]:
                why += (f" (its poses cover {self.pose_times[0]:.3f} to {self.pose_times[-1]:.3f} s, the images "
                        f"{self.timestamps[0]:.3f} to {self.timestamps[-1]:.3f} s)")
        return f"{missing} of {len(self)} frames have no ground-truth pose: {why}"

    def _intrinsics(self) -> np.ndarray:
        path = self.root / "intrinsics.txt"
        if path.exists():
            lines = list(_data_lines(path))
            try:
                fx, fy, cx, cy = (float(v) for v in lines[0][1].split())
                if not all(np.isfinite([fx, fy, cx, cy])) or min(fx, fy, cx, cy) <= 0:
                    raise ValueError
            except (IndexError, ValueError):
                raise DatasetError(f"{path}: expected one line 'fx fy cx cy' of positive numbers") from None
        else:
            match = re.search(r"freiburg[123]", self.name)
            if not match:
                raise DatasetError(
                    f"{self.root}: cannot tell the camera: the folder name has no freiburg1/2/3 and there is no "
                    f"intrinsics.txt (one line 'fx fy cx cy')"
                )
            fx, fy, cx, cy = INTRINSICS[match.group()]
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])

    def __len__(self) -> int:
        return len(self.rgb_files)

    def frame_name(self, i: int) -> str:
        """Frame `i`'s name: its colour image's file stem, which names its annotation too."""
        return Path(self.rgb_files[i]).stem

    def trajectory(self) -> tuple[np.ndarray, list[Pose | None]]:
        return self.timestamps.copy(), list(self.poses)

    def _annotation_path(self, i: int) -> Path:
        return self.root / "annotations" / "instances" / f"{self.frame_name(i)}.png"

    def _annotation(self, i: int, shape: tuple[int, int]) -> np.ndarray | None:
        path = self._annotation_path(i)
        if not path.exists():
            return None
        ids = read_instance_ids(path)
        if ids.shape != shape:
            raise DatasetError(f"{path}: instance image is {ids.shape}, the depth image {shape}")
        unknown = np.setdiff1d(np.unique(ids), [0, *self._objects])
        if len(unknown):
            raise DatasetError(f"{path}: object id {unknown[0]} is not in annotations/objects.csv")
        return ids

    def _depth(self, i: int) -> np.ndarray:
        return read_depth(self.root / self.depth_files[i], DEPTH_FACTOR)

    def __getitem__(self, i: int) -> Frame:
        i = self._check_index(i)
        depth = self._depth(i)
        rgb = resize_rgb(read_image(self.root / self.rgb_files[i], "RGB"), depth.shape)
        intrinsics = intrinsics_for(self.intrinsics, depth.shape, self.root / self.depth_files[i])
        return Frame(i, float(self.timestamps[i]), rgb, depth, intrinsics, self.poses[i],
                     self._annotation(i, depth.shape), name=self.frame_name(i))

    @cached_property
    def _objects(self) -> dict[int, tuple[str, str]]:
        """Annotation id -> (class, description) from annotations/objects.csv (empty without it)."""
        path = self.root / "annotations" / "objects.csv"
        return read_objects_table(path) if path.exists() else {}

    def instances(self) -> list[Instance]:
        """Annotated objects: masked depth of every annotated frame with a pose, in the world frame."""
        clouds: dict[int, list[np.ndarray]] = {object_id: [] for object_id in self._objects}
        for i, pose in enumerate(self.poses):
            if pose is None or not self._annotation_path(i).exists():
                continue
            depth = self._depth(i)  # the colour image is not needed here
            instances = self._annotation(i, depth.shape)
            sample = np.zeros(depth.shape, bool)
            sample[::ANNOTATION_STRIDE, ::ANNOTATION_STRIDE] = True
            valid = sample & (instances > 0) & (depth > 0)
            intrinsics = intrinsics_for(self.intrinsics, depth.shape, self.root / self.depth_files[i])
            points = pose.apply(backproject(depth, intrinsics, valid))
            ids = instances[valid]  # same row-major order as backproject's pixels
            order = np.argsort(ids, kind="stable")
            unique, starts = np.unique(ids[order], return_index=True)
            for object_id, chunk in zip(unique, np.split(points[order], starts[1:])):
                clouds[int(object_id)].append(chunk)
        return [
            Instance(object_id, name, description,
                     np.concatenate(clouds[object_id]) if clouds[object_id] else np.zeros((0, 3)))
            for object_id, (name, description) in self._objects.items()
        ]

    def object_classes(self) -> dict[int, str]:
        return {object_id: name for object_id, (name, _) in self._objects.items() if not is_structure(name)}

    def descriptions(self) -> dict[int, str]:
        return {object_id: text for object_id, (name, text) in self._objects.items() if not is_structure(name)}
