"""YOLO-seg as a detector back-end (ultralytics, weights needed), and the one COCO-to-map class table.

COCO classes are mapped to a map's vocabulary by `COCO_TO_MAP` (first name the map has wins;
otherwise the COCO name itself when the map has it; else the detection is dropped):
`coco_to_vocabulary` builds that lookup for any COCO-labelled source (`COCO_NAMES`: the 80
classes by COCO-80 id, the order YOLO models use).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from clipclique.errors import ModelUnavailableError
from clipclique.perception.detectors import empty_detections, vocabulary_index
from clipclique.perception.encoders import host_reachable
from clipclique.types import Detections, Frame

# The 80 COCO classes by their COCO-80 id (YOLO's class ids).
COCO_NAMES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat", "traffic light",
    "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog", "horse", "sheep", "cow",
    "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella", "handbag", "tie", "suitcase", "frisbee",
    "skis", "snowboard", "sports ball", "kite", "baseball bat", "baseball glove", "skateboard", "surfboard",
    "tennis racket", "bottle", "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple",
    "sandwich", "orange", "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch",
    "potted plant", "bed", "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard", "cell phone",
    "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors", "teddy bear",
    "hair drier", "toothbrush",
)

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
    reads_instances = False

    def __init__(self, model, class_names: list[str], confidence: float = 0.25, device: str | None = None) -> None:
        self.model = model
        self.class_names = class_names
        self.confidence = confidence
        self.device = device
        self.name = f"yolo:{Path(str(getattr(model, 'ckpt_path', None) or 'model')).name}"
        self.class_map = coco_to_vocabulary(class_names, model.names)

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
            raise ModelUnavailableError(f"--yolo-weights {weights}: a {model.task} model; instance "
                                        "masks need a -seg model")
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


def coco_to_vocabulary(class_names: list[str], model_names: dict[int, str] | None = None) -> np.ndarray:
    """Lookup array: detector class id -> map class id, -1 where the map has no such class.

    `model_names` (class id -> COCO name) is the detector's own table (a YOLO model's `names`);
    by default COCO-80 (`COCO_NAMES`)."""
    if model_names is None:
        model_names = dict(enumerate(COCO_NAMES))
    vocabulary = vocabulary_index(class_names)
    out = np.full(max(model_names) + 1, -1, int)
    for index, coco in model_names.items():
        for candidate in COCO_TO_MAP.get(coco, (coco,)):
            if candidate.lower() in vocabulary:
                out[index] = vocabulary[candidate.lower()]
                break
    return out
