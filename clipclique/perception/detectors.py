"""The detector interface (`detect(frame) -> Detections` in the map's class vocabulary) and the
detector that needs no model: `InstanceDetector` reads the frame's instance image (ScanNet 2D
instances, a generated scene) or the TUM object annotations, each object id mapped to its class
through the dataset's object table. The paper queries with ground-truth instances.

The other back-ends: YOLO-seg in `clipclique.perception.yolo`, the simulated detectors in
`clipclique.sim.detectors`; `clipclique.backends.make_detector` picks one by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, Protocol

import numpy as np
from numba import njit

from clipclique.types import Detections, Frame


class Detector(Protocol):
    name: str
    simulated: bool
    reads_instances: bool  # its input is the frame's instance image: a frame without one has nothing to detect

    def detect(self, frame: Frame) -> Detections: ...


def empty_detections(height: int, width: int) -> Detections:
    return Detections(np.zeros((0, height, width), bool), np.zeros((0, 4)), np.zeros(0, int), np.zeros(0),
                      np.zeros(0, int), masks_in_boxes=True)


def mask_boxes(masks: np.ndarray) -> np.ndarray:
    """(K, 4) xyxy pixel boxes (inclusive min, exclusive max) of (K, H, W) non-empty masks."""
    rows, cols = masks.any(axis=2), masks.any(axis=1)
    height, width = masks.shape[1:]
    y0, x0 = rows.argmax(axis=1), cols.argmax(axis=1)
    y1 = height - rows[:, ::-1].argmax(axis=1)
    x1 = width - cols[:, ::-1].argmax(axis=1)
    return np.column_stack((x0, y0, x1, y1)).astype(float)


def instance_boxes(instances: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The positive ids of an instance image (ascending), their pixel counts and `mask_boxes` of their
    masks: one compiled pass over the image where the ids are small enough to index a table (a sort
    and one pass per mask otherwise)."""
    top = int(instances.max(initial=0))
    if top > max(instances.size, 1 << 16):  # ids too large to index a table by
        ids, counts = np.unique(instances[instances > 0], return_counts=True)
        return ids, counts, mask_boxes(instances[None] == ids[:, None, None])
    counts, boxes = _instance_table(np.ascontiguousarray(instances), top)
    ids = np.flatnonzero(counts)
    return ids.astype(instances.dtype), counts[ids], boxes[ids].astype(np.float64)


@njit(cache=True)
def _instance_table(instances: np.ndarray, top: int) -> tuple[np.ndarray, np.ndarray]:
    """Per id 0..top: its pixel count and its xyxy box (inclusive min, exclusive max); id 0 and
    negative ids are not counted. A row is read as runs of one id (objects are contiguous), each run
    counted and boxed once; a run is followed eight pixels a step (one comparison of eight, which the
    compiler vectorizes), then pixel by pixel to its end."""
    height, width = instances.shape
    counts = np.zeros(top + 1, np.int64)
    boxes = np.empty((top + 1, 4), np.int64)
    boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3] = width, height, 0, 0
    for v in range(height):
        row = instances[v]
        u = 0
        while u < width:
            value, start = row[u], u
            u += 1
            while u + 8 <= width and ((row[u] == value) & (row[u + 1] == value) & (row[u + 2] == value)
                                      & (row[u + 3] == value) & (row[u + 4] == value) & (row[u + 5] == value)
                                      & (row[u + 6] == value) & (row[u + 7] == value)):
                u += 8
            while u < width and row[u] == value:
                u += 1
            if value > 0:
                counts[value] += u - start
                boxes[value, 0] = min(boxes[value, 0], start)
                boxes[value, 1] = min(boxes[value, 1], v)
                boxes[value, 2] = max(boxes[value, 2], u)
                boxes[value, 3] = v + 1  # rows come in order: the last one seen is the lowest
    return counts, boxes


def id_counts(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`np.unique(ids, return_counts=True)`, counted without its sort where the ids are small enough: an image
    of signed ids (a crop of the instance image) in one compiled pass over it as it lies (no copy), others by
    numpy's `bincount`."""
    if ids.size and ids.ndim == 2 and ids.dtype.kind == "i":
        counts = _id_table(ids, max(ids.size, 1024))
        if counts is None:
            return np.unique(ids, return_counts=True)
    elif ids.size == 0 or ids.min() < 0 or ids.max() > max(ids.size, 1024):
        return np.unique(ids, return_counts=True)
    else:
        counts = np.bincount(ids.ravel())
    present = np.flatnonzero(counts)
    return present.astype(ids.dtype), counts[present]


@njit(cache=True)
def _id_table(ids: np.ndarray, largest: int) -> np.ndarray | None:
    """`np.bincount` of a 2-D id image (None where an id is negative or above `largest`): its range, then the
    counts, each in one pass over the rows."""
    low, high = ids[0, 0], ids[0, 0]
    for v in range(ids.shape[0]):
        for u in range(ids.shape[1]):
            low, high = min(low, ids[v, u]), max(high, ids[v, u])
    if low < 0 or high > largest:
        return None
    counts = np.zeros(high + 1, np.int64)
    for v in range(ids.shape[0]):
        for u in range(ids.shape[1]):
            counts[ids[v, u]] += 1
    return counts


def box_masks(instances: np.ndarray, ids: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(K, H, W) masks of `ids` in an instance image, each compared inside its box (`instance_boxes`) only:
    the same masks as comparing the whole image per id, at the cost of the boxes' area (compiled: no
    temporary per mask). The masks are numpy's zeros (calloc: the pages outside every box are never
    written), filled in place."""
    instances = np.ascontiguousarray(instances)
    masks = np.zeros((len(ids), *instances.shape), bool)
    _fill_box_masks(masks.reshape(-1), instances, np.asarray(ids), np.asarray(boxes).astype(np.int64).reshape(-1, 4))
    return masks


@njit(cache=True)
def _fill_box_masks(masks: np.ndarray, instances: np.ndarray, ids: np.ndarray, boxes: np.ndarray) -> None:
    """`box_masks` into the flat zeros `masks`, with integer boxes (clipped to the image), on flat arrays indexed
    by unsigned integers so that the compiler vectorizes each row's comparison."""
    height, width = instances.shape
    image = instances.ravel()
    for k in range(len(ids)):
        object_id = ids[k]
        x0, y0 = max(boxes[k, 0], 0), max(boxes[k, 1], 0)
        x1, y1 = min(boxes[k, 2], width), min(boxes[k, 3], height)
        for v in range(y0, y1):
            row = np.uint64(v * width)
            out = np.uint64(k * height * width) + row
            for u in range(x0, x1):
                t = np.uint64(u)
                masks[out + t] = image[row + t] == object_id


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
    reads_instances: ClassVar[bool] = True

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
        ids, counts, boxes = instance_boxes(frame.instances)
        classes = np.array([self._map_class.get(int(i), -1) for i in ids], int)
        keep = (classes >= 0) & (counts >= self.min_pixels)
        ids, classes, boxes = ids[keep], classes[keep], boxes[keep]
        return Detections(box_masks(frame.instances, ids, boxes), boxes, classes, np.ones(len(ids)), ids.astype(int),
                          masks_in_boxes=True)
