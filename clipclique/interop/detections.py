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
from functools import cached_property
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from clipclique.datasets.tum import MAX_TIME_DIFF, associate
from clipclique.interop.boxfit import BoxSegmentation, box_mask
from clipclique.interop.coco import (
    coco_results,
    read_coco_results,
    read_image_list,
    write_json,
)
from clipclique.interop.errors import InteropError
from clipclique.interop.labels import COCO, LabelSet, class_lookup, text_matches
from clipclique.io.safeio import read_json
from clipclique.types import Detections, Frame

if TYPE_CHECKING:
    from clipclique.datasets import Sequence
    from clipclique.perception.encoders import Encoder

DUPLICATE_IOU = 0.7  # two boxes of different classes overlapping this much are one object


@dataclass
class FileDetection:
    class_name: str  # the name in the file's label set (COCO's by default)
    box: np.ndarray  # (4,) xyxy pixels
    score: float
    mask: np.ndarray | None = None  # (H, W) bool, from a COCO results file
    ellipse: np.ndarray | None = None  # VOOM's [cx, cy, width, height, angle_rad]


def frame_key(name: str) -> str:
    """A file name as frames are matched: no folder, no extension (`rgb/1.5.png` -> `1.5`)."""
    base = PurePosixPath(name.replace("\\", "/")).name
    stem, dot, suffix = base.rpartition(".")
    return stem if dot and suffix.lower() in ("png", "jpg", "jpeg", "bmp", "tif", "tiff") else base


MIN_SIDE_PX = 1.0  # an ellipse axis or a box side under this is no object: skipped (VOOM writes a few)


@dataclass
class DetectionFile:
    """The detections of a file by frame key, and the degenerate entries left out of them."""

    frames: dict[str, list[FileDetection]]
    total: int = 0  # entries read, skipped ones included
    skipped: dict[str, int] = field(default_factory=dict)  # why -> how many

    def notes(self, path: Path) -> list[str]:
        """One warning line for the skipped entries ("7 of 14,071 detections skipped: zero-size ellipse")."""
        if not self.skipped:
            return []
        alone = len(self.skipped) == 1
        reasons = ", ".join(why if alone else f"{count:,} {why}" for why, count in self.skipped.items())
        return [f"{path.name}: {sum(self.skipped.values()):,} of {self.total:,} detections skipped: {reasons} "
                "(--strict-detections refuses the file instead)"]


def _box(value: object, where: str) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == 4
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise InteropError(f"{where}: bbox should be [x1, y1, x2, y2], got {str(value)[:60]}")
    box = np.array(value, dtype=np.float64)
    if not np.isfinite(box).all() or box[2] < box[0] or box[3] < box[1]:
        raise InteropError(f"{where}: bbox {value} is not a box with x2 > x1 and y2 > y1")
    return box


def _ellipse(value: object, where: str) -> np.ndarray | None:
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == 5
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            and np.isfinite(value).all() and value[2] >= 0 and value[3] >= 0):
        raise InteropError(f"{where}: ellipse should be [cx, cy, width > 0, height > 0, angle_rad]")
    return np.array(value, dtype=np.float64)


def _degenerate(box: np.ndarray, ellipse: np.ndarray | None) -> str | None:
    """Why an entry is no object (an axis or side under MIN_SIDE_PX), None when it is one."""
    if ellipse is not None and min(ellipse[2], ellipse[3]) < MIN_SIDE_PX:
        return "zero-size ellipse"
    if min(box[2] - box[0], box[3] - box[1]) < MIN_SIDE_PX:
        return "box under 1 pixel"
    return None


def read_detection_json(path: Path, labels: LabelSet = COCO, strict: bool = False) -> DetectionFile:
    """The detections of an OA-SLAM / VOOM / GOReloc detection file, category ids in `labels`; degenerate
    entries skipped and counted (refused, naming the entry, when `strict`)."""
    data = read_json(path, "detection file", InteropError)
    if not isinstance(data, list):
        raise InteropError(f"{path}: a detection file is a JSON list of {{'file_name', 'detections'}}")
    read = DetectionFile({})
    for index, entry in enumerate(data):
        where = f"{path}, entry {index}"
        if not (isinstance(entry, dict) and isinstance(entry.get("file_name"), (str, int))
                and isinstance(entry.get("detections"), list)):
            raise InteropError(f"{where}: needs 'file_name' and a 'detections' list")
        detections = read.frames.setdefault(frame_key(str(entry["file_name"])), [])
        for number, item in enumerate(entry["detections"]):
            spot = f"{where}, detection {number}"
            if not isinstance(item, dict):
                raise InteropError(f"{spot}: not an object")
            category, score = item.get("category_id"), item.get("detection_score", item.get("score"))
            if not isinstance(category, int) or isinstance(category, bool):
                raise InteropError(f"{spot}: category_id {category!r} is not an integer")
            if not (isinstance(score, (int, float)) and not isinstance(score, bool) and 0 <= score <= 1):
                raise InteropError(f"{spot}: detection_score {score!r} is not a number in [0, 1]")
            box, ellipse = _box(item.get("bbox"), spot), _ellipse(item.get("ellipse"), spot)
            name = labels.name(category, spot)
            read.total += 1
            if why := _degenerate(box, ellipse):
                if strict:
                    raise InteropError(f"{spot}: a {why} (--strict-detections; without it such entries are skipped)")
                read.skipped[why] = read.skipped.get(why, 0) + 1
                continue
            detections.append(FileDetection(name, box, float(score), ellipse=ellipse))
    return read


def read_detections(path: Path, images: Path | None = None, labels: LabelSet = COCO,
                    strict: bool = False) -> DetectionFile:
    """The detections of either format (sniffed from the first entry); `labels` names the ids of a detection
    JSON (COCO results name theirs by COCO's own ids); `strict` refuses a degenerate entry of one."""
    data = read_json(path, "detection file", InteropError)
    if isinstance(data, list) and data and isinstance(data[0], dict) and "image_id" in data[0]:
        images = images or path.parent / "images.json"
        if not images.is_file():
            raise InteropError(f"{path}: COCO results name images by id; give the image list with "
                               f"--detector file:{path},images=FILE (no {images})")
        out: dict[str, list[FileDetection]] = {}
        results = read_coco_results(path, read_image_list(images))
        for result in results:
            out.setdefault(frame_key(result.image), []).append(
                FileDetection(result.class_name, result.box, result.score, result.mask))
        return DetectionFile(out, len(results))
    return read_detection_json(path, labels, strict)


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
    """Detections of a file, in the map's vocabulary (`clipclique.interop.labels.class_lookup`: COCO classes
    mapped as YOLO's are, LVIS names through their COCO class); box-only ones segmented from the depth (boxfit)."""

    path: Path
    read: DetectionFile
    class_names: list[str]
    min_score: float = 0.0
    segmentation: BoxSegmentation = field(default_factory=BoxSegmentation)
    simulated: bool = False
    by_text: dict[str, int] = field(default_factory=dict)  # class names met by text embeddings (`meet_by_text`)
    reads_instances: ClassVar[bool] = False

    @property
    def name(self) -> str:
        return f"file:{self.path.name}"

    @classmethod
    def load(cls, spec: str, class_names: list[str], min_score: float = 0.0, labels: LabelSet = COCO,
             strict: bool = False) -> FileDetector:
        path, images = parse_spec(spec)
        return cls(path, read_detections(path, images, labels, strict), class_names, min_score)

    @property
    def table(self) -> dict[str, list[FileDetection]]:
        return self.read.frames

    @cached_property
    def _lookup(self) -> dict[str, int]:
        """Detection class name -> map class id; names missing are dropped."""
        return class_lookup(self.class_names) | self.by_text

    def meet_by_text(self, encoder: Encoder | None) -> list[str]:
        """Meet the file's class names that no table holds through their text embeddings where `encoder` is a
        real CLIP (`clipclique.interop.labels.text_matches`); the note saying which were met, and which not."""
        tables = class_lookup(self.class_names)
        unmet = sorted({d.class_name for listed in self.table.values() for d in listed
                        if d.class_name.lower() not in tables})
        found = text_matches(unmet, self.class_names, encoder) if encoder is not None else {}
        if not found:
            return []
        self.by_text = {name.lower(): index for name, (index, _) in found.items()}
        self.__dict__.pop("_lookup", None)
        met = ", ".join(f"{name!r} as {self.class_names[index]!r} ({cosine:.2f})"
                        for name, (index, cosine) in found.items())
        left = [name for name in unmet if name not in found]
        return [f"{self.path.name}: {len(found)} classes met by their text embeddings ({encoder.name}): {met}"
                + (f"; {len(left)} without a counterpart (first {left[0]!r})" if left else "")]

    def check_coverage(self, sequence: Sequence, selected: range) -> list[str]:
        """Before a run: an error naming both naming schemes when the file covers none of the selected frames
        (another sequence's file); the notes to print: skipped entries, and the count below half coverage."""
        found = [sequence.frame_name(i) in self.table for i in selected]
        stamps, _ = self._stamps
        if len(stamps) and not all(found):  # a bag's frames meet a TUM folder's file by colour stamp
            timestamps = sequence.trajectory()[0][selected.start:selected.stop:selected.step]
            found = [by_name or by_stamp for by_name, by_stamp in
                     zip(found, associate(timestamps, stamps, MAX_TIME_DIFF) >= 0)]
        covered = sum(by_name or str(i) in self.table for by_name, i in zip(found, selected))
        if covered == 0:
            theirs = next(iter(self.table), None)
            named = f"names frames like {theirs!r}" if theirs is not None else "names no frame"
            raise InteropError(f"{self.path}: {named}; {sequence.name}'s are like {sequence.frame_name(selected[0])!r} "
                               f"or numbers 0..{len(sequence) - 1}: covered 0 of {len(selected)} frames "
                               "(a detection file of another sequence?)")
        notes = self.read.notes(self.path)
        if covered * 2 < len(selected):
            notes.append(f"{self.path.name} covered {covered} of {len(selected)} frames; the others have no detections")
        return notes

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
        lookup = self._lookup
        kept = [d for d in listed if d.score >= self.min_score and d.class_name.lower() in lookup]
        boxes = np.array([d.box for d in kept]).reshape(-1, 4)
        class_ids = np.array([lookup[d.class_name.lower()] for d in kept], dtype=np.int64)
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
                masks[row] = box_mask(frame.depth, frame.intrinsics, detection.box, detection.ellipse,
                                      self.segmentation)
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

