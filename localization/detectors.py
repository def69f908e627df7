"""Detector back-ends of clipclique-loc behind one interface: `detect(frame) -> Detections` in the map's
class vocabulary. `--detector gt`, `annotations`, `simulated` and `simulated-yolo` are the library's
`clipclique.detectors`; this module adds the one that needs a model:

- `YoloDetector`: YOLO instance segmentation through ultralytics; COCO classes are mapped to
  the map's vocabulary by `COCO_TO_MAP` (first name the map has wins; otherwise the COCO name
  itself when the map has it; else the detection is dropped).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from clipclique.detectors import (
    Detector,
    InstanceDetector,
    SimulatedDetector,
    SimulatedYoloDetector,
    empty_detections,
    vocabulary_index,
)
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
    """The back-end a `--detector` value names: gt | annotations | simulated | simulated-yolo | yolo."""
    if kind == "gt":
        return InstanceDetector(object_classes, class_names)
    if kind == "annotations":
        return InstanceDetector(object_classes, class_names, name="annotations")
    if kind == "simulated":
        return SimulatedDetector(InstanceDetector(object_classes, class_names), seed=seed)
    if kind == "simulated-yolo":
        return SimulatedYoloDetector(InstanceDetector(object_classes, class_names), seed=seed)
    if kind == "yolo":
        return YoloDetector.load(yolo_weights, class_names)
    raise ClipcliqueError(f"--detector {kind!r}: choose gt, annotations, simulated, simulated-yolo or yolo")
