"""Colours and annotation ids shared by every recording, so a class looks the same everywhere."""

from __future__ import annotations

import numpy as np
import rerun as rr
from matplotlib.colors import hsv_to_rgb

_GOLDEN = 0.618033988749895  # hue step: consecutive classes land far apart on the colour wheel

CORRECT = np.array([60, 200, 80], dtype=np.uint8)
WRONG = np.array([230, 50, 50], dtype=np.uint8)
UNKNOWN = np.array([160, 160, 160], dtype=np.uint8)
GT_CAMERA = np.array([255, 255, 255], dtype=np.uint8)
ESTIMATE_CAMERA = np.array([255, 200, 0], dtype=np.uint8)


def class_colors(class_names: list[str]) -> np.ndarray:
    """(C, 3) uint8 colours, one per class, deterministic in the vocabulary order."""
    index = np.arange(len(class_names))
    hsv = np.column_stack(
        ((0.08 + index * _GOLDEN) % 1.0, np.where(index % 2, 0.55, 0.8), np.where(index % 3 == 2, 0.75, 0.95))
    )
    return np.round(hsv_to_rgb(hsv) * 255).astype(np.uint8).reshape(-1, 3)


def annotation_ids(class_ids: np.ndarray) -> np.ndarray:
    """Map-vocabulary class ids as annotation-context ids: 0 is reserved for background."""
    return np.asarray(class_ids, dtype=np.int64) + 1


def annotation_context(class_names: list[str]) -> rr.AnnotationContext:
    """Class labels and colours for segmentation images, boxes and ellipsoids (ids from `annotation_ids`)."""
    colors = class_colors(class_names)
    infos = [rr.AnnotationInfo(id=0, label="background", color=(0, 0, 0, 0))]
    infos += [
        rr.AnnotationInfo(id=int(i), label=name, color=tuple(int(c) for c in color))
        for i, name, color in zip(annotation_ids(np.arange(len(class_names))), class_names, colors)
    ]
    return rr.AnnotationContext(infos)


def correctness_colors(correct: np.ndarray) -> np.ndarray:
    """(M, 3) colours from `match_correctness` codes: green correct, red wrong, grey unknown."""
    return np.select(
        [correct[:, None] == 1, correct[:, None] == 0], [CORRECT, WRONG], UNKNOWN
    ).astype(np.uint8)


def match_correctness(observation_instances: np.ndarray, landmark_instances: np.ndarray) -> np.ndarray:
    """Per match: 1 same object, 0 different, -1 unknown (the observation has no ground-truth object:
    a false detection, or a dataset without instance labels; metrics count these as wrong)."""
    observation_instances = np.asarray(observation_instances)
    same = (observation_instances == np.asarray(landmark_instances)).astype(np.int64)
    return np.where(observation_instances < 0, -1, same)
