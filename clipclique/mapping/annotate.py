"""`clipclique-map annotate`: the object annotations of a TUM-format sequence, from instance masks made
with another tool.

In: instance-id PNGs (8- or 16-bit, 0 = no object), each named after its colour image (the file stem
rgb.txt lists, or the image's timestamp in any notation: `1305031102.175304.png`, `1305031102.1753.png`),
and an `id,class,description` table of the ids; or a COCO annotation file (RLE or polygon masks, each
with the object's id across images, images named as above; read by clipclique.interop.coco), whose
categories give the classes unless such a table does. Out: `annotations/objects.csv` and
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

from clipclique.datasets.base import description_template, read_instance_ids
from clipclique.datasets.tum import MAX_TIME_DIFF, TumSequence, associate, read_objects_table
from clipclique.errors import DatasetError
from clipclique.interop.coco import read_coco_annotations


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
    check_not_annotated(sequence)
    objects = read_objects_table(table)
    if not masks.is_dir():
        raise DatasetError(f"--masks {masks}: not a folder of instance PNGs")
    files = sorted(masks.glob("*.png"))
    if not files:
        raise DatasetError(f"--masks {masks}: holds no .png instance masks")
    frames = frames_of(sequence, [path.stem for path in files], [str(path) for path in files])
    images = {}
    for path, i in zip(files, frames):
        ids = read_instance_ids(path)
        check_mask(sequence, i, ids, str(path))
        if unknown := sorted(set(np.unique(ids).tolist()) - {0} - set(objects)):
            raise DatasetError(f"{path}: object id {unknown[0]} is not in {table}")
        images[i] = ids.astype(np.uint16)
    return write_annotations(sequence, images, objects)


def annotate_coco(sequence: TumSequence, coco: Path, table: Path | None) -> AnnotationReport:
    """The annotations of a COCO annotation file (RLE or polygon masks, an object id per annotation): classes
    from its categories, descriptions "a photo of a <class>", unless `table` gives them by object id."""
    check_not_annotated(sequence)
    masks = read_coco_annotations(coco)
    if not masks:
        raise DatasetError(f"{coco}: holds no annotations")
    named = read_objects_table(table) if table is not None else {}
    objects: dict[int, tuple[str, str]] = {}
    for mask in masks:
        if named and mask.object_id not in named:
            raise DatasetError(f"{coco}: object id {mask.object_id} ({mask.image}) is not in {table}")
        entry = named.get(mask.object_id) or (mask.class_name, description_template(mask.class_name))
        if objects.setdefault(mask.object_id, entry)[0] != entry[0]:
            raise DatasetError(f"{coco}: object id {mask.object_id} is a {objects[mask.object_id][0]} in one image and "
                               f"a {entry[0]} in {mask.image}")
    names = sorted({mask.image for mask in masks})
    frames = dict(zip(names, frames_of(sequence, [Path(name).stem for name in names],
                                       [f"{coco}: image {name}" for name in names])))
    images: dict[int, np.ndarray] = {}
    for mask in masks:  # later annotations paint over earlier ones where masks overlap
        i = frames[mask.image]
        ids = images.setdefault(i, np.zeros(mask.mask.shape, np.uint16))
        check_mask(sequence, i, ids, f"{coco}: image {mask.image}")
        ids[mask.mask] = mask.object_id
    return write_annotations(sequence, images, named | objects)


def check_not_annotated(sequence: TumSequence) -> None:
    target = sequence.root / "annotations"
    if target.exists():
        raise DatasetError(f"{target}: exists already; annotate never replaces annotations (move it away first)")


def check_mask(sequence: TumSequence, frame: int, ids: np.ndarray, where: str) -> None:
    depth_shape = sequence[frame].depth.shape
    if ids.shape != depth_shape:
        raise DatasetError(f"{where}: mask is {ids.shape[1]} x {ids.shape[0]}, the depth image of its frame "
                           f"{depth_shape[1]} x {depth_shape[0]}")


def write_annotations(sequence: TumSequence, images: dict[int, np.ndarray],
                      objects: dict[int, tuple[str, str]]) -> AnnotationReport:
    """annotations/objects.csv and annotations/instances/<rgb stem>.png, appearing whole or not at all."""
    target = sequence.root / "annotations"
    staging = Path(tempfile.mkdtemp(prefix=".annotations-", dir=sequence.root))
    try:
        (staging / "instances").mkdir()
        (staging / "objects.csv").write_text(objects_csv(objects), encoding="utf-8")
        for i, ids in images.items():
            Image.fromarray(ids).save(staging / "instances" / f"{sequence.frame_name(i)}.png")
        staging.chmod(0o755)  # mkdtemp makes it private
        os.replace(staging, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    seen = set().union(*(np.unique(ids).tolist() for ids in images.values())) - {0}
    without_pose = [sequence.frame_name(i) for i in sorted(images) if sequence.poses[i] is None]
    return AnnotationReport(target, len(images), without_pose, len(objects), sorted(set(objects) - seen))


def frames_of(sequence: TumSequence, stems: list[str], where: list[str]) -> list[int]:
    """The frame index each mask belongs to, by its colour image's file stem or by its timestamp (within
    the TUM association's 0.02 s); a mask that names no frame, or a second mask of one frame, is refused
    (`where`: how each mask is named in a message)."""
    by_stem = {sequence.frame_name(i): i for i in range(len(sequence))}
    frames: list[int] = []
    for stem, named in zip(stems, where):
        i = by_stem.get(stem)
        if i is None:
            try:
                stamp = float(stem)
            except ValueError:
                stamp = math.nan
            if math.isfinite(stamp):
                i = int(associate(np.array([stamp]), sequence.timestamps)[0])
            if i is None or i < 0:
                raise DatasetError(f"{named}: names no colour image of {sequence.root / 'rgb.txt'} (name a mask after "
                                   f"the image's file stem or its timestamp, within {MAX_TIME_DIFF} s)")
        if i in frames:
            raise DatasetError(f"{named}: a second mask of frame {sequence.frame_name(i)} "
                               f"(the first: {where[frames.index(i)]})")
        frames.append(i)
    return frames


def objects_csv(objects: dict[int, tuple[str, str]]) -> str:
    """annotations/objects.csv: `id,class,description`, one row per object."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(("id", "class", "description"))
    writer.writerows((object_id, name, description) for object_id, (name, description) in objects.items())
    return text.getvalue()
