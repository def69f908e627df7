"""`clipclique-map annotate`: the object annotations of a TUM-format sequence, from instance masks made
with another tool.

In: instance-id PNGs (8- or 16-bit, 0 = no object), each named after its colour image (the file stem
rgb.txt lists, or the image's timestamp in any notation: `1305031102.175304.png`, `1305031102.1753.png`),
and an `id,class,description` table of the ids. Out: `annotations/objects.csv` and
`annotations/instances/<rgb stem>.png` (16-bit) in the sequence folder, the layout the TUM reader and
`clipclique-map build` read. Every mask is checked against the sequence first (its frame, the depth
image's size, ids the table names); the folder appears whole or not at all, and existing annotations
are never replaced.
"""

from __future__ import annotations

import csv
import io
import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from clipclique.datasets.base import read_instance_ids
from clipclique.datasets.tum import MAX_TIME_DIFF, TumSequence, associate, read_objects_table
from clipclique.errors import DatasetError


@dataclass
class AnnotationReport:
    """What `annotate` wrote."""

    folder: Path  # the sequence's annotations/
    frames: int  # annotated frames
    without_pose: list[str]  # annotated frames (rgb stems) with no ground-truth pose: the map cannot use them
    objects: int  # rows of objects.csv
    unseen: list[int]  # ids of the table that no mask shows


def annotate(sequence: TumSequence, masks: Path, table: Path) -> AnnotationReport:
    """Check every mask in `masks` against `sequence` and the ids of `table`, then write the annotations."""
    target = sequence.root / "annotations"
    if target.exists():
        raise DatasetError(f"{target}: exists already; annotate never replaces annotations (move it away first)")
    objects = read_objects_table(table)
    if not masks.is_dir():
        raise DatasetError(f"--masks {masks}: not a folder of instance PNGs")
    files = sorted(masks.glob("*.png"))
    if not files:
        raise DatasetError(f"--masks {masks}: holds no .png instance masks")
    frames = frames_of(sequence, files)
    seen: set[int] = set()
    images = {}
    for path, i in zip(files, frames):
        ids = read_instance_ids(path)
        depth_shape = sequence[i].depth.shape
        if ids.shape != depth_shape:
            raise DatasetError(f"{path}: mask is {ids.shape[1]} x {ids.shape[0]}, the depth image of its frame "
                               f"{depth_shape[1]} x {depth_shape[0]}")
        present = set(np.unique(ids).tolist()) - {0}
        if unknown := sorted(present - set(objects)):
            raise DatasetError(f"{path}: object id {unknown[0]} is not in {table}")
        seen |= present
        images[sequence.frame_name(i)] = ids.astype(np.uint16)
    staging = Path(tempfile.mkdtemp(prefix=".annotations-", dir=sequence.root))
    try:
        (staging / "instances").mkdir()
        (staging / "objects.csv").write_text(objects_csv(objects), encoding="utf-8")
        for stem, ids in images.items():
            Image.fromarray(ids).save(staging / "instances" / f"{stem}.png")
        staging.chmod(0o755)  # mkdtemp makes it private
        os.replace(staging, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    without_pose = [sequence.frame_name(i) for i in frames if sequence.poses[i] is None]
    return AnnotationReport(target, len(files), without_pose, len(objects), sorted(set(objects) - seen))


def frames_of(sequence: TumSequence, files: list[Path]) -> list[int]:
    """The frame index each mask belongs to, by its colour image's file stem or by its timestamp (within
    the TUM association's 0.02 s); a mask that names no frame, or a second mask of one frame, is refused."""
    by_stem = {sequence.frame_name(i): i for i in range(len(sequence))}
    frames: list[int] = []
    for path in files:
        i = by_stem.get(path.stem)
        if i is None:
            try:
                stamp = float(path.stem)
            except ValueError:
                stamp = math.nan
            if math.isfinite(stamp):
                i = int(associate(np.array([stamp]), sequence.timestamps)[0])
            if i is None or i < 0:
                raise DatasetError(f"{path}: names no colour image of {sequence.root / 'rgb.txt'} (name a mask after "
                                   f"the image's file stem or its timestamp, within {MAX_TIME_DIFF} s)")
        if i in frames:
            raise DatasetError(f"{path}: a second mask of frame {sequence.frame_name(i)} "
                               f"(the first: {files[frames.index(i)]})")
        frames.append(i)
    return frames


def objects_csv(objects: dict[int, tuple[str, str]]) -> str:
    """annotations/objects.csv: `id,class,description`, one row per object."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(("id", "class", "description"))
    writer.writerows((object_id, name, description) for object_id, (name, description) in objects.items())
    return text.getvalue()
