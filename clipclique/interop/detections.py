"""`--detector file:PATH`: detections read from a file instead of a model.

Two formats (docs/import_export.md), told apart by their entries:
- the OA-SLAM / VOOM / GOReloc detection JSON: `[{"file_name", "detections": [{"category_id"
  (COCO-80), "detection_score", "bbox": [x1, y1, x2, y2], "ellipse" (VOOM, optional)}]}]`, boxes
  only: each object's pixels come from the depth inside its box (`clipclique.interop.boxfit`);
- COCO results with RLE masks (`[{"image_id", "category_id" (COCO-91), "bbox": [x, y, w, h],
  "score", "segmentation"}]`), images named through an image list (`images=FILE`, default
  `images.json` beside the results): what `--detector yolo` writes into its run folder.
Frames are matched by file name without folder or extension (`rgb/1311868164.36.png` matches
the frame `1311868164.36`); else by timestamp, a name that is a stamp (`1311868164.36`, with a decimal
point) meeting the frame whose colour stamp is within MAX_TIME_DIFF of it (TUM's pairing rule: the
detections of a TUM folder apply to the same recording's bag); else by frame index when the file
names frames by number.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar
from functools import cached_property
from pathlib import Path, PurePosixPath

import numpy as np

from clipclique.datasets.tum import MAX_TIME_DIFF, associate
from clipclique.interop.boxfit import BoxSegmentation, box_mask
from clipclique.interop.coco import (
    COCO80_INDEX,
    coco80_name,
    coco_results,
    read_coco_results,
    read_image_list,
    write_json,
)
from clipclique.interop.errors import InteropError
from clipclique.io.safeio import read_json
from clipclique.types import Detections, Frame
from clipclique.perception.yolo import coco_to_vocabulary

DUPLICATE_IOU = 0.7  # two boxes of different classes overlapping this much are one object


@dataclass
class FileDetection:
    class_name: str  # COCO name
    box: np.ndarray  # (4,) xyxy pixels
    score: float
    mask: np.ndarray | None = None  # (H, W) bool, from a COCO results file
    ellipse: np.ndarray | None = None  # VOOM's [cx, cy, width, height, angle_rad]


def frame_key(name: str) -> str:
    """A file name as frames are matched: no folder, no extension (`rgb/1.5.png` -> `1.5`)."""
    base = PurePosixPath(name.replace("\\", "/")).name
    stem, dot, suffix = base.rpartition(".")
    return stem if dot and suffix.lower() in ("png", "jpg", "jpeg", "bmp", "tif", "tiff") else base


def _box(value: object, where: str) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == 4
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise InteropError(f"{where}: bbox should be [x1, y1, x2, y2], got {str(value)[:60]}")
    box = np.array(value, dtype=np.float64)
    if not np.isfinite(box).all() or box[2] <= box[0] or box[3] <= box[1]:
        raise InteropError(f"{where}: bbox {value} is not a box with x2 > x1 and y2 > y1")
    return box


def read_detection_json(path: Path) -> dict[str, list[FileDetection]]:
    """Frame key -> detections of an OA-SLAM / VOOM / GOReloc detection file."""
    data = read_json(path, "detection file", InteropError)
    if not isinstance(data, list):
        raise InteropError(f"{path}: a detection file is a JSON list of {{'file_name', 'detections'}}")
    out: dict[str, list[FileDetection]] = {}
    for index, entry in enumerate(data):
        where = f"{path}, entry {index}"
        if not (isinstance(entry, dict) and isinstance(entry.get("file_name"), (str, int))
                and isinstance(entry.get("detections"), list)):
            raise InteropError(f"{where}: needs 'file_name' and a 'detections' list")
        detections = out.setdefault(frame_key(str(entry["file_name"])), [])
        for number, item in enumerate(entry["detections"]):
            spot = f"{where}, detection {number}"
            if not isinstance(item, dict):
                raise InteropError(f"{spot}: not an object")
            category, score = item.get("category_id"), item.get("detection_score", item.get("score"))
            if not isinstance(category, int) or isinstance(category, bool):
                raise InteropError(f"{spot}: category_id {category!r} is not an integer")
            if not (isinstance(score, (int, float)) and not isinstance(score, bool) and 0 <= score <= 1):
                raise InteropError(f"{spot}: detection_score {score!r} is not a number in [0, 1]")
            ellipse = item.get("ellipse")
            if ellipse is not None:
                if not (isinstance(ellipse, list) and len(ellipse) == 5
                        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in ellipse)
                        and np.isfinite(ellipse).all() and ellipse[2] > 0 and ellipse[3] > 0):
                    raise InteropError(f"{spot}: ellipse should be [cx, cy, width > 0, height > 0, angle_rad]")
                ellipse = np.array(ellipse, dtype=np.float64)
            detections.append(FileDetection(coco80_name(category, spot), _box(item.get("bbox"), spot), float(score),
                                            ellipse=ellipse))
    return out


def read_detections(path: Path, images: Path | None = None) -> dict[str, list[FileDetection]]:
    """Frame key -> detections of either format (sniffed from the first entry)."""
    data = read_json(path, "detection file", InteropError)
    if isinstance(data, list) and data and isinstance(data[0], dict) and "image_id" in data[0]:
        images = images or path.parent / "images.json"
        if not images.is_file():
            raise InteropError(f"{path}: COCO results name images by id; give the image list with "
                               f"--detector file:{path},images=FILE (no {images})")
        out: dict[str, list[FileDetection]] = {}
        for result in read_coco_results(path, read_image_list(images)):
            out.setdefault(frame_key(result.image), []).append(
                FileDetection(result.class_name, result.box, result.score, result.mask))
        return out
    return read_detection_json(path)


def parse_spec(spec: str) -> tuple[Path, Path | None]:
    """`file:PATH[,images=LIST]` -> (PATH, LIST)."""
    body = spec.removeprefix("file:")
    path, _, option = body.partition(",images=")
    if not path:
        raise InteropError(f"--detector {spec!r}: expected file:PATH or file:RESULTS.json,images=IMAGES.json")
    return Path(path), Path(option) if option else None


def merged_duplicates(boxes: np.ndarray, class_ids: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """Indices kept after cross-class duplicates (boxes of different classes with IoU >= DUPLICATE_IOU,
    one cup reported as cup and as bottle) keep only their best-scored report."""
    order = np.argsort(-scores, kind="stable")
    kept: list[int] = []
    for i in order:
        if not any(class_ids[j] != class_ids[i] and _iou(boxes[i], boxes[j]) >= DUPLICATE_IOU for j in kept):
            kept.append(int(i))
    return np.array(sorted(kept), dtype=np.int64)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    width = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    height = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = width * height
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


@dataclass
class FileDetector:
    """Detections of a file, in the map's vocabulary (COCO classes mapped as YOLO's are); box-only ones
    segmented from the depth (boxfit)."""

    path: Path
    table: dict[str, list[FileDetection]]
    class_names: list[str]
    min_score: float = 0.0
    segmentation: BoxSegmentation = field(default_factory=BoxSegmentation)
    simulated: bool = False
    reads_instances: ClassVar[bool] = False

    @property
    def name(self) -> str:
        return f"file:{self.path.name}"

    @classmethod
    def load(cls, spec: str, class_names: list[str], min_score: float = 0.0) -> FileDetector:
        path, images = parse_spec(spec)
        return cls(path, read_detections(path, images), class_names, min_score)

    @cached_property
    def _vocabulary(self) -> np.ndarray:
        """COCO-80 id -> map class id (-1: dropped), by the COCO table YOLO uses (`clipclique.perception.yolo`)."""
        return coco_to_vocabulary(self.class_names)

    @cached_property
    def _stamps(self) -> tuple[np.ndarray, list[str]]:
        """(stamps, names) of the names that are timestamps (a number with a decimal point; `12` is an index)."""
        found = []
        for key in self.table:
            if "." not in key:
                continue
            try:
                found.append((float(key), key))
            except ValueError:
                continue
        return np.array([stamp for stamp, _ in found], np.float64), [key for _, key in found]

    def listed(self, frame: Frame) -> list[FileDetection]:
        """The frame's detections: by name, else by colour stamp within MAX_TIME_DIFF, else by index."""
        if frame.name in self.table:
            return self.table[frame.name]
        stamps, names = self._stamps
        nearest = associate(np.array([frame.timestamp], np.float64), stamps, MAX_TIME_DIFF)[0]
        return self.table[names[nearest]] if nearest >= 0 else self.table.get(str(frame.index), [])

    def detect(self, frame: Frame) -> Detections:
        height, width = frame.depth.shape
        listed = self.listed(frame)
        vocabulary, index = self._vocabulary, COCO80_INDEX
        kept = [d for d in listed if d.score >= self.min_score and vocabulary[index[d.class_name]] >= 0]
        boxes = np.array([d.box for d in kept]).reshape(-1, 4)
        class_ids = np.array([vocabulary[index[d.class_name]] for d in kept], dtype=np.int64)
        scores = np.array([d.score for d in kept], dtype=np.float64)
        keep = merged_duplicates(boxes, class_ids, scores)
        masks = np.zeros((len(keep), height, width), bool)
        for row, k in enumerate(keep):
            detection = kept[k]
            if detection.mask is not None:
                if detection.mask.shape != (height, width):
                    raise InteropError(f"{self.path}: a mask of {frame.name} is {detection.mask.shape[1]}x"
                                       f"{detection.mask.shape[0]}, the image {width}x{height}")
                masks[row] = detection.mask
            else:
                masks[row] = box_mask(frame.depth, frame.intrinsics, detection.box, detection.ellipse, self.segmentation)
        return Detections(masks, boxes[keep], class_ids[keep], scores[keep], np.full(len(keep), -1, dtype=np.int64))


@dataclass
class CocoRecorder:
    """The detections of a run, kept to be written as a COCO results file with RLE masks and its image list."""

    class_names: list[str]  # the map's vocabulary the detections' class ids index
    coco_names: dict[str, str]  # map class -> the COCO class the detector reported for it
    entries: list[dict] = field(default_factory=list)
    images: list[dict] = field(default_factory=list)

    def add(self, frame: Frame, detections: Detections) -> None:
        names = [self.coco_names.get(self.class_names[c], "") for c in detections.class_ids]
        self.images.append({"id": frame.index, "file_name": frame.name})
        self.entries += coco_results([frame.index] * len(detections), names, detections.boxes, detections.scores,
                                     detections.masks)

    def write(self, results: Path, images: Path) -> None:
        write_json(results, self.entries)
        write_json(images, {"images": self.images})

