"""Detector back-ends behind one interface: `detect(frame) -> Detections` in the map's class vocabulary.

- `InstanceDetector`: the frame's ground-truth instance image (ScanNet 2D instances, the demo)
  or the TUM object annotations, each object id mapped to its class through the dataset's
  object table. The paper queries with ground-truth instances.
- `SimulatedDetector`: ground truth degraded, seeded per frame: misses, false positives
  (blobs on whatever surface is there) and class confusions. Named "simulated" everywhere.
- `YoloDetector`: YOLO instance segmentation through ultralytics; COCO classes are mapped to
  the map's vocabulary by `COCO_TO_MAP` (first name the map has wins; otherwise the COCO name
  itself when the map has it; else the detection is dropped).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Protocol

import numpy as np

from clipclique.encoders import host_reachable
from clipclique.errors import ClipcliqueError, ModelUnavailableError
from clipclique.types import Detections, Frame

# COCO class -> candidate names in a map vocabulary (ScanNet NYU40 / raw categories, TUM annotations).
COCO_TO_MAP: dict[str, tuple[str, ...]] = {
    "dining table": ("table", "desk", "dining table"),
    "couch": ("sofa", "couch"),
    "tv": ("television", "tv", "monitor"),
    "refrigerator": ("refrigerator", "refridgerator", "fridge"),
    "potted plant": ("plant", "potted plant"),
    "book": ("books", "book"),
    "cup": ("cup", "mug"),
    "backpack": ("backpack", "bag"),
    "handbag": ("handbag", "bag"),
    "suitcase": ("suitcase", "bag"),
    "teddy bear": ("teddy bear", "stuffed animal", "toy"),
    "mouse": ("mouse", "computer mouse"),
    "cell phone": ("phone", "cell phone"),
    "remote": ("remote", "remote control"),
    "bed": ("bed",),
    "toilet": ("toilet",),
    "sink": ("sink",),
    "chair": ("chair", "office chair"),
}


class Detector(Protocol):
    name: str
    simulated: bool

    def detect(self, frame: Frame) -> Detections: ...


def empty_detections(height: int, width: int) -> Detections:
    return Detections(np.zeros((0, height, width), bool), np.zeros((0, 4)), np.zeros(0, int), np.zeros(0),
                      np.zeros(0, int))


def mask_boxes(masks: np.ndarray) -> np.ndarray:
    """(K, 4) xyxy pixel boxes (inclusive min, exclusive max) of (K, H, W) non-empty masks."""
    rows, cols = masks.any(axis=2), masks.any(axis=1)
    height, width = masks.shape[1:]
    y0, x0 = rows.argmax(axis=1), cols.argmax(axis=1)
    y1 = height - rows[:, ::-1].argmax(axis=1)
    x1 = width - cols[:, ::-1].argmax(axis=1)
    return np.column_stack((x0, y0, x1, y1)).astype(float)


def vocabulary_index(class_names: list[str]) -> dict[str, int]:
    return {name.lower(): i for i, name in enumerate(class_names)}


@dataclass
class InstanceDetector:
    """Detections read off the frame's instance image (ground truth, or TUM annotations)."""

    object_classes: dict[int, str]  # dataset object id -> class name
    class_names: list[str]  # the map's vocabulary
    name: str = "ground-truth"
    min_pixels: int = 1
    simulated: bool = False

    @cached_property
    def _map_class(self) -> dict[int, int]:
        """Dataset object id -> map class id (-1: not in the map's vocabulary), fixed for the run."""
        vocabulary = vocabulary_index(self.class_names)
        return {i: vocabulary.get(name.lower(), -1) for i, name in self.object_classes.items()}

    def detect(self, frame: Frame) -> Detections:
        height, width = frame.depth.shape
        if frame.instances is None:
            return empty_detections(height, width)
        ids, counts = np.unique(frame.instances[frame.instances > 0], return_counts=True)
        classes = np.array([self._map_class.get(int(i), -1) for i in ids], int)
        keep = (classes >= 0) & (counts >= self.min_pixels)
        ids, classes = ids[keep], classes[keep]
        masks = frame.instances[None] == ids[:, None, None]
        return Detections(masks, mask_boxes(masks), classes, np.ones(len(ids)), ids.astype(int))


@dataclass
class SimulatedDetector:
    """Ground truth with seeded misses, false positives and class confusions (a stand-in for a real detector)."""

    truth: InstanceDetector
    miss_rate: float = 0.1  # probability each true object is not detected
    false_positives: float = 0.5  # expected spurious detections per frame (Poisson)
    confusion_rate: float = 0.05  # probability a detection gets a wrong class
    seed: int = 0
    simulated: bool = True

    @property
    def name(self) -> str:
        return "simulated"

    def detect(self, frame: Frame) -> Detections:
        rng = np.random.default_rng([self.seed, frame.index])
        true = self.truth.detect(frame)
        height, width = frame.depth.shape
        kept = rng.random(len(true)) >= self.miss_rate
        class_ids = true.class_ids[kept].copy()
        confused = rng.random(len(class_ids)) < self.confusion_rate
        class_ids[confused] = self._other_class(rng, class_ids[confused])
        spurious = self._blobs(rng, rng.poisson(self.false_positives), height, width)
        masks = np.concatenate((true.masks[kept], spurious))
        return Detections(
            masks,
            mask_boxes(masks) if len(masks) else np.zeros((0, 4)),
            np.concatenate((class_ids, rng.integers(0, len(self.truth.class_names), len(spurious)))).astype(int),
            np.concatenate((rng.uniform(0.6, 1.0, len(class_ids)), rng.uniform(0.3, 0.7, len(spurious)))),
            np.concatenate((true.instance_ids[kept], np.full(len(spurious), -1))).astype(int),
        )

    def _other_class(self, rng: np.random.Generator, class_ids: np.ndarray) -> np.ndarray:
        count = len(self.truth.class_names)
        if count < 2:
            return class_ids
        return (class_ids + rng.integers(1, count, len(class_ids))) % count

    @staticmethod
    def _blobs(rng: np.random.Generator, count: int, height: int, width: int) -> np.ndarray:
        """Elliptic masks of random size and place: detections of nothing in particular."""
        v, u = np.mgrid[:height, :width]
        centers = rng.uniform((0, 0), (height, width), (count, 2))
        radii = rng.uniform(0.05, 0.15, (count, 2)) * min(height, width)
        return (((v[None] - centers[:, 0, None, None]) / radii[:, 0, None, None]) ** 2
                + ((u[None] - centers[:, 1, None, None]) / radii[:, 1, None, None]) ** 2) <= 1.0


class YoloDetector:
    """YOLO-seg (ultralytics); detections whose COCO class the map lacks are dropped."""

    simulated = False

    def __init__(self, model, class_names: list[str], confidence: float = 0.25, device: str | None = None) -> None:
        self.model = model
        self.class_names = class_names
        self.confidence = confidence
        self.device = device
        self.name = f"yolo:{Path(str(getattr(model, 'ckpt_path', None) or 'model')).name}"
        self.class_map = coco_to_vocabulary(model.names, class_names)

    @classmethod
    def load(cls, weights: str | Path, class_names: list[str], confidence: float = 0.25,
             device: str | None = None) -> YoloDetector:
        """Weights from a local file, or a model name ultralytics downloads when online.

        Unless the user set YOLO_OFFLINE, ultralytics is kept offline (no update checks, no usage
        analytics) except when the weights must be downloaded and github.com is reachable.
        """
        weights = str(weights)
        local = Path(weights).is_file()
        if "YOLO_OFFLINE" not in os.environ:
            os.environ["YOLO_OFFLINE"] = "1" if local or not host_reachable("github.com") else "0"
        os.environ.setdefault("YOLO_AUTOINSTALL", "false")
        if not local and _env_true("YOLO_OFFLINE"):
            raise ModelUnavailableError(
                f"--yolo-weights {weights}: no such file and no network to download it; pass a local "
                "YOLO-seg checkpoint (e.g. --yolo-weights path/to/yolov8x-seg.pt) or use --detector gt")
        try:
            from ultralytics import YOLO
        except ImportError as error:
            raise ModelUnavailableError(f"--detector yolo needs the ultralytics package ({error})") from None
        try:
            model = YOLO(weights)
        except Exception as error:  # download and unpickling failures come in many types
            raise ModelUnavailableError(f"--yolo-weights {weights}: cannot load ({error})") from None
        if model.task != "segment":
            raise ModelUnavailableError(f"--yolo-weights {weights}: a {model.task} model; instance masks need a -seg model")
        return cls(model, class_names, confidence, device)

    def detect(self, frame: Frame) -> Detections:
        height, width = frame.rgb.shape[:2]
        result = self.model.predict(np.ascontiguousarray(frame.rgb[..., ::-1]),  # ultralytics reads arrays as BGR
                                    conf=self.confidence, retina_masks=True, verbose=False, device=self.device)[0]
        if result.masks is None or len(result.boxes) == 0:
            return empty_detections(height, width)
        classes = self.class_map[result.boxes.cls.cpu().numpy().astype(int)]
        keep = classes >= 0
        masks = result.masks.data.cpu().numpy()[keep] > 0.5
        return Detections(masks, result.boxes.xyxy.cpu().numpy()[keep].astype(float), classes[keep],
                          result.boxes.conf.cpu().numpy()[keep].astype(float), np.full(int(keep.sum()), -1))


def _env_true(name: str) -> bool:
    """An environment flag read as ultralytics reads it (1, true, yes, on, y, t)."""
    return os.environ.get(name, "").strip().lower() in ("1", "true", "yes", "on", "y", "t")


def coco_to_vocabulary(model_names: dict[int, str], class_names: list[str]) -> np.ndarray:
    """Lookup array: detector class id -> map class id, -1 where the map has no such class."""
    vocabulary = vocabulary_index(class_names)
    out = np.full(max(model_names) + 1, -1, int)
    for index, coco in model_names.items():
        for candidate in COCO_TO_MAP.get(coco, (coco,)):
            if candidate.lower() in vocabulary:
                out[index] = vocabulary[candidate.lower()]
                break
    return out


def make_detector(kind: str, object_classes: dict[int, str], class_names: list[str],
                  yolo_weights: str | Path = "yolov8x-seg.pt", seed: int = 0) -> Detector:
    """The back-end a `--detector` value names: gt | annotations | simulated | yolo."""
    if kind == "gt":
        return InstanceDetector(object_classes, class_names)
    if kind == "annotations":
        return InstanceDetector(object_classes, class_names, name="annotations")
    if kind == "simulated":
        return SimulatedDetector(InstanceDetector(object_classes, class_names), seed=seed)
    if kind == "yolo":
        return YoloDetector.load(yolo_weights, class_names)
    raise ClipcliqueError(f"--detector {kind!r}: choose gt, annotations, simulated or yolo")
