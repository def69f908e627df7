"""Pairs of object maps of one place made the way real ones differ (issue 38): two detectors with their own
misses, false positives and class confusions, one with a coarser vocabulary, text embeddings that cannot be
compared, and little overlap. What `tools/fit_align_confidence.py` fits the alignment confidence on, and what
the tests hold it to: such pairs give few-correspondence wrong answers that must not look confident.

Vocabularies (`detector_pair(..., vocabulary=)`): "generic" names the classes class0..class11; "coco" gives both
maps twelve COCO names; "lvis" gives the map COCO names and the query map each class's LVIS synonym
(`lookalikes.LVIS_TO_COCO`: sofa for couch, mug for cup, ...), as an LVIS-vocabulary map meets a COCO one. The
geometry, misses and confusions of a seed are the same in every vocabulary."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from clipclique.sim.poses import random_rotation
from clipclique.sim.synthetic import synthetic_map
from clipclique.types import Ellipsoids, Map, Pose

VOCABULARIES = ("generic", "coco", "lvis")
COCO = ["keyboard", "mouse", "cup", "tv", "couch", "laptop", "book", "chair", "bottle", "dining table", "remote",
        "potted plant"]
LVIS = ["computer keyboard", "mouse (computer equipment)", "mug", "television set", "sofa", "laptop computer",
        "notebook", "armchair", "water bottle", "kitchen table", "remote control", "flowerpot"]


def detector_map(room: Map, rng: np.random.Generator, miss: float, extra: float, confuse: float,
                 noise_m: float, merge: int = 0) -> Map:
    """`room` as one detector maps it: a share `miss` of the landmarks missed, `confuse` of the rest given another
    class, false positives (`extra` of the count) of random classes inside the room's box, centres jittered by
    `noise_m`; `merge` > 0 folds the last `merge` classes onto the first ones (a coarser vocabulary)."""
    kept = room.subset(np.flatnonzero(rng.random(len(room)) > miss))
    classes = kept.class_ids.copy()
    confused = rng.random(len(classes)) < confuse
    classes[confused] = rng.integers(0, len(room.class_names), int(confused.sum()))
    count = int(round(extra * len(kept)))
    low, high = room.ellipsoids.centers.min(axis=0), room.ellipsoids.centers.max(axis=0)
    centers = np.concatenate((kept.ellipsoids.centers, rng.uniform(low, high, (count, 3))))
    centers = centers + rng.normal(scale=noise_m, size=centers.shape)
    axes = np.concatenate((kept.ellipsoids.axes, rng.uniform(0.1, 0.6, (count, 3))))
    rotations = np.concatenate((kept.ellipsoids.rotations, np.repeat(np.eye(3)[None], count, axis=0)))
    classes = np.concatenate((classes, rng.integers(0, len(room.class_names), count)))
    names = list(room.class_names)
    if merge:
        keep = len(names) - merge
        classes = np.where(classes >= keep, classes % keep, classes)
        names = names[:keep]
    ids = np.concatenate((kept.instance_ids, -np.arange(1, count + 1)))
    return Map(Ellipsoids(centers, axes, rotations), classes, names, [f"{names[c]}" for c in classes], ids,
               None, "none", {"simulated": True})


def detector_pair(rng: np.random.Generator, vocabulary: str = "generic") -> tuple[Map, Map, Pose]:
    """(query map, map, the true query-to-map transform) of one room mapped by two detectors over parts that
    overlap by 0.3-1.2 m (few shared landmarks), the query moved by a random transform; class names as
    `vocabulary` says (module docstring)."""
    if vocabulary not in VOCABULARIES:
        raise ValueError(f"vocabulary {vocabulary!r} is not one of {', '.join(VOCABULARIES)}")
    room = synthetic_map(rng, int(rng.integers(30, 60)), num_classes=12)
    if vocabulary != "generic":
        room = replace(room, class_names=list(COCO))
    x = room.ellipsoids.centers[:, 0]
    cut, band = rng.uniform(2.0, 3.0), rng.uniform(0.3, 1.2)
    first = detector_map(room.subset(np.flatnonzero(x < cut + band)), rng, miss=rng.uniform(0.1, 0.4),
                         extra=rng.uniform(0.0, 0.3), confuse=rng.uniform(0.0, 0.2), noise_m=0.03)
    second = detector_map(room.subset(np.flatnonzero(x > cut - band)), rng, miss=rng.uniform(0.1, 0.4),
                          extra=rng.uniform(0.0, 0.3), confuse=rng.uniform(0.0, 0.2), noise_m=0.05,
                          merge=int(rng.integers(0, 4)))
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    if vocabulary == "lvis":
        first = replace(first, class_names=list(LVIS), descriptions=[LVIS[c] for c in first.class_ids])
    return first.transformed(truth.inverse()), second, truth
