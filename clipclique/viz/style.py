"""Colours and annotation ids shared by every recording, so a class looks the same everywhere."""

from __future__ import annotations

import hashlib

import numpy as np
import pyarrow as pa
import rerun as rr

MIN_LUMINANCE = 0.5  # class colours are at least this light: labels are drawn in them on the viewer's dark background
PALETTE_HUES = 16  # class colours: 16 hues, each in 3 shades; two classes share a colour or differ visibly
PALETTE_SHADES = ((0.8, 1.0), (0.45, 0.95), (0.6, 0.75))  # (saturation, value)

CORRECT = np.array([60, 200, 80], dtype=np.uint8)
WRONG = np.array([230, 50, 50], dtype=np.uint8)
UNKNOWN = np.array([160, 160, 160], dtype=np.uint8)
GT_CAMERA = np.array([255, 255, 255], dtype=np.uint8)
ESTIMATE_CAMERA = np.array([255, 200, 0], dtype=np.uint8)


def class_colors(class_names: list[str]) -> np.ndarray:
    """(C, 3) uint8 colours picked from `palette()` by a hash of each class name: a class has the same colour
    in every map and recording, whatever the vocabulary around it."""
    slots = [int.from_bytes(hashlib.blake2b(name.strip().lower().encode(), digest_size=4).digest(), "little")
             for name in class_names]
    colors = palette()
    return colors[np.array(slots, dtype=np.int64) % len(colors)].reshape(-1, 3)


def palette() -> np.ndarray:
    """(PALETTE_HUES * len(PALETTE_SHADES), 3) uint8: evenly spaced hues in each shade, lightened where needed
    so that labels drawn in them stay readable on the viewer's dark background (dark blues and purples)."""
    hues = np.arange(PALETTE_HUES) / PALETTE_HUES
    hsv = np.vstack([np.column_stack(((hues + k / (len(PALETTE_SHADES) * PALETTE_HUES)) % 1.0,
                                      np.full(PALETTE_HUES, saturation), np.full(PALETTE_HUES, value)))
                     for k, (saturation, value) in enumerate(PALETTE_SHADES)])
    rgb = hsv_to_rgb(hsv)
    luminance = rgb @ np.array([0.2126, 0.7152, 0.0722])
    whiten = np.clip((MIN_LUMINANCE - luminance) / (1.0 - luminance), 0.0, 1.0)[:, None]
    return np.round((rgb + whiten * (1.0 - rgb)) * 255).astype(np.uint8)


HSV_SECTORS = np.array([[0, 3, 2], [1, 0, 2], [2, 0, 3], [2, 1, 0], [3, 2, 0], [0, 2, 1]])  # per sixth of the
# hue circle, which of (v, q, p, t) of `hsv_to_rgb` are red, green and blue


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(N, 3) hue, saturation, value in [0, 1] as (N, 3) RGB in [0, 1]: the textbook six sectors, matplotlib's
    arithmetic (a recording need not import matplotlib for 48 colours)."""
    hue, saturation, value = np.asarray(hsv, dtype=np.float64).T
    sector = (hue * 6.0).astype(np.int64)
    fraction = hue * 6.0 - sector
    options = np.stack((value, value * (1.0 - saturation * fraction), value * (1.0 - saturation),
                        value * (1.0 - saturation * (1.0 - fraction))))
    return options[HSV_SECTORS[sector % 6], np.arange(len(hue))[:, None]]


def annotation_ids(class_ids: np.ndarray) -> np.ndarray:
    """Map-vocabulary class ids as annotation-context ids: 0 is reserved for background."""
    return np.asarray(class_ids, dtype=np.int64) + 1


def annotation_context(class_names: list[str]) -> rr.AnnotationContext:
    """Class labels and colours for segmentation images, boxes and ellipsoids (ids from `annotation_ids`).

    Built as its Arrow array: Rerun's own conversion (`rr.AnnotationContext(infos)`) casts an array, which imports
    pyarrow.compute (about 0.1 s of every recorded run's start) for nothing else."""
    ids = [0, *annotation_ids(np.arange(len(class_names))).tolist()]
    labels = ["background", *class_names]
    colors = [0, *(int.from_bytes(bytes([*color, 255]), "big") for color in class_colors(class_names).tolist())]  # RGBA
    context = [{"class_id": i, "class_description": {"info": {"id": i, "label": label, "color": color},
                                                     "keypoint_annotations": [], "keypoint_connections": []}}
               for i, label, color in zip(ids, labels, colors)]
    arrow_type = rr.components.AnnotationContextBatch(None).as_arrow_array().type
    return rr.AnnotationContext(context=pa.array([context], type=arrow_type))


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
