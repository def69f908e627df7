"""Detectors that need no model: the frame's own instance image, and a simulated detector built on it.

- `InstanceDetector`: the frame's ground-truth instance image (ScanNet 2D instances, the demo)
  or the TUM object annotations, each object id mapped to its class through the dataset's
  object table. The paper queries with ground-truth instances.
- `SimulatedDetector`: ground truth degraded, seeded per frame: misses, false positives
  (blobs on whatever surface is there) and class confusions. Named "simulated" everywhere.

They live in the library (not in the clipclique-loc tool) so that a library user can go from a
dataset frame to a pose without the CLI; YOLO-seg, which needs ultralytics and weights, is a
back-end of the tool (`localization/detectors.py`).
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
