"""Classes a detector confuses with each other, and the class-similarity kernel built from them.

Real detectors mislabel look-alike objects far more often than others: on TUM fr2/desk a third
of YOLO's detections of mapped objects carry another class, nearly all from the first pairs
below (COCO names; the rest are their NYU40 / ScanNet-category counterparts). An exact-label
descriptor treats such an observation as matching nothing; the kernel lets it still vote, with a
reduced weight, for the landmarks whose class it resembles. The map side is never softened: the
map was built from annotations, only the query detector confuses.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

# Unordered pairs of class names that a detector mistakes for one another.
LOOKALIKE_PAIRS: tuple[tuple[str, str], ...] = (
    ("cup", "bottle"),
    ("cup", "wine glass"),
    ("cup", "vase"),
    ("cup", "bowl"),
    ("vase", "bottle"),
    ("book", "cell phone"),
    ("book", "books"),
    ("mouse", "cell phone"),
    ("remote", "cell phone"),
    ("knife", "fork"),
    ("spoon", "fork"),
    ("knife", "spoon"),
    ("chair", "teddy bear"),
    ("chair", "couch"),
    ("chair", "office chair"),
    ("tv", "laptop"),
    ("tv", "monitor"),
    ("tv", "television"),
    ("dining table", "desk"),
    ("dining table", "table"),
    ("desk", "table"),
    ("couch", "sofa"),
    ("cabinet", "kitchen cabinet"),
    ("cabinet", "dresser"),
    ("cabinet", "nightstand"),
    ("shelf", "bookshelf"),
    ("curtain", "shower curtain"),
    ("towel", "clothes"),
    ("counter", "kitchen counter"),
)

# Unordered pairs of names that two vocabularies give one class (COCO, NYU40 / ScanNet, free text): a
# map of one vocabulary aligned to a map of another matches them as the same class
# (clipclique.multiframe.mapalign). Each pair is a look-alike pair too.
SYNONYM_PAIRS: tuple[tuple[str, str], ...] = (
    ("couch", "sofa"),
    ("tv", "monitor"),
    ("tv", "television"),
    ("book", "books"),
    ("dining table", "table"),
    ("shelf", "bookshelf"),
    ("counter", "kitchen counter"),
    ("cabinet", "kitchen cabinet"),
)


# LVIS name -> the COCO class it is (or is a kind of); LVIS names equal to a COCO name map to themselves.
# The one table of the two label sets (clipclique.interop.labels reads ids through it; `synonym` matches by it).
LVIS_TO_COCO: dict[str, str] = {
    "car (automobile)": "car", "bus (vehicle)": "bus", "train (railroad vehicle)": "train", "fireplug": "fire hydrant",
    "necktie": "tie", "ball": "sports ball", "soccer ball": "sports ball", "tennis ball": "sports ball",
    "wineglass": "wine glass", "orange (fruit)": "orange", "doughnut": "donut", "sofa": "couch",
    "flowerpot": "potted plant", "television set": "tv", "monitor (computer equipment) computer monitor": "tv",
    "laptop computer": "laptop", "mouse (computer equipment)": "mouse", "remote control": "remote",
    "computer keyboard": "keyboard", "cellular telephone": "cell phone", "microwave oven": "microwave",
    "hair dryer": "hair drier", "ski": "skis", "mug": "cup", "teacup": "cup", "armchair": "chair",
    "folding chair": "chair", "water bottle": "bottle", "wine bottle": "bottle", "beer bottle": "bottle",
    "kitchen table": "dining table", "desk": "dining table", "table": "dining table", "notebook": "book",
}


def synonym(name: str, vocabulary: list[str]) -> int | None:
    """Index in `vocabulary` of `name` (any case) or of a synonym of it (SYNONYM_PAIRS, or the same COCO class
    by LVIS_TO_COCO: an LVIS map's `computer keyboard` and a COCO map's `keyboard`); None when neither is there."""
    index = {entry.lower(): i for i, entry in enumerate(vocabulary)}
    name = name.lower()
    if name in index:
        return index[name]
    found = next((index[b if a == name else a] for a, b in SYNONYM_PAIRS
                  if name in (a, b) and (b if a == name else a) in index), None)
    if found is None:
        coco = LVIS_TO_COCO.get(name, name)
        found = next((i for entry, i in index.items() if LVIS_TO_COCO.get(entry, entry) == coco), None)
    return found


def class_kernel(class_names: list[str], lookalike_weight: float) -> sp.csr_matrix:
    """(C, C) sparse kernel: 1 on the diagonal, `lookalike_weight` between look-alike classes of the vocabulary."""
    index = {name.lower(): i for i, name in enumerate(class_names)}
    rows, cols = [], []
    if lookalike_weight > 0:
        for a, b in LOOKALIKE_PAIRS:
            if a in index and b in index:
                rows += [index[a], index[b]]
                cols += [index[b], index[a]]
    count = len(class_names)
    diagonal = np.arange(count)
    data = np.r_[np.ones(count), np.full(len(rows), lookalike_weight)]
    kernel = sp.csr_matrix((data, (np.r_[diagonal, rows], np.r_[diagonal, cols])), shape=(count, count))
    kernel.sum_duplicates()
    return kernel
