"""The detector interface (`detect(frame) -> Detections` in the map's class vocabulary) and the
detector that needs no model: `InstanceDetector` reads the frame's instance image (ScanNet 2D
instances, a generated scene) or the TUM object annotations, each object id mapped to its class
through the dataset's object table. The paper queries with ground-truth instances.

The other back-ends: YOLO-seg in `clipclique.yolo`, the simulated detectors in
`clipclique.sim.detectors`; `clipclique.backends.make_detector` picks one by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np

from clipclique.types import Detections, Frame


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

    @cached_property
    def mapped_ids(self) -> frozenset[int]:
        """Dataset object ids whose class the map's vocabulary has."""
        return frozenset(i for i, c in self._map_class.items() if c >= 0)

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
