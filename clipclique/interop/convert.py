"""An `ImportedMap` to a clipclique `Map` (classes settled, descriptions, text embeddings, class
distributions), and a `Map` back out as an OA-SLAM text map or a clipclique JSON landmark list."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from clipclique.datasets import description_template
from clipclique.datasets.tum import read_objects_table
from clipclique.interop.coco import COCO80_INDEX
from clipclique.interop.errors import InteropError
from clipclique.interop.maps import LANDMARKS_FORMAT, LANDMARKS_VERSION, ImportedMap
from clipclique.interop.quadric import encode_dual_quadric
from clipclique.perception.encoders import Encoder
from clipclique.perception.yolo import COCO_TO_MAP
from clipclique.types import Map
from clipclique.version import __version__


def read_objects(path: Path) -> dict[int, tuple[str, str]]:
    """Object id -> (class, description) of an objects.csv (`id,class,description`), any id up to 64 bits."""
    return read_objects_table(path, max_id=2**64 - 1, error=InteropError)


def to_map(imported: ImportedMap, where: str, objects: dict[int, tuple[str, str]] | None = None,
           encoder: Encoder | None = None, sha256: str | None = None, labels: str | None = None) -> Map:
    """The clipclique map of imported landmarks: classes (and descriptions) from `objects` by object id
    where given, else the file's; InteropError naming `where` for a landmark left without a class. `sha256`, the
    input's digest, lets a later import of the same file replace this map (`clipclique.mapping.run`); `labels`, the
    label set its category ids were read in (`lvis`: `clipclique.interop.labels.met_by` reads it)."""
    objects = objects or {}
    classes, descriptions = [], []
    for index, (object_id, name, description) in enumerate(zip(imported.object_ids, imported.classes,
                                                               imported.descriptions)):
        if object_id in objects:
            name, description = objects[object_id]
        if name is None:
            hint = "; give classes with --objects objects.csv" if not objects else (f" (id {object_id} is not in "
                                                                                    "--objects)")
            raise InteropError(f"{where}: object {index} (id {object_id}) has no class{hint}")
        classes.append(name)
        descriptions.append(description or description_template(name))
    unmatched = sorted(set(objects) - set(imported.object_ids))
    notes = list(imported.notes)
    if unmatched:
        notes.append(f"--objects names {len(unmatched)} ids the map does not hold (first {unmatched[0]})")
    vocabulary = sorted(set(classes) | {c for d in imported.distributions if d for c in d})
    index = {name: i for i, name in enumerate(vocabulary)}
    class_ids = np.array([index[name] for name in classes], np.int64)
    distributions = None
    if any(d is not None for d in imported.distributions):
        distributions = np.zeros((len(classes), len(vocabulary)))
        distributions[np.arange(len(classes)), class_ids] = 1.0
        for row, (distribution, object_id) in enumerate(zip(imported.distributions, imported.object_ids)):
            if distribution is not None and object_id not in objects:
                distributions[row] = 0.0
                for name, p in distribution.items():
                    distributions[row, index[name]] = p
                distributions[row] /= distributions[row].sum()
    embeddings = None if encoder is None else np.asarray(encoder.encode_text(descriptions), np.float32)
    record = {
        "source": {"kind": "import", "format": imported.source.value, "file": where, "synthetic": False,
                   "name": imported.frame or unaligned_name(where)} | ({"sha256": sha256} if sha256 else {})
                  | ({"labels": labels} if labels else {}),
        "source_object_ids": [int(i) for i in imported.object_ids],
        "notes": notes,
        "encoder_simulated": bool(encoder is not None and getattr(encoder, "simulated", False)),
        "tool": "clipclique-map import",
        "version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    return Map(imported.ellipsoids, class_ids, vocabulary, descriptions, np.array(imported.instance_ids, np.int64),
               embeddings, encoder.name if encoder else "none", record, distributions)


def unaligned_name(where: str) -> str:
    """The source name of a map in another system's own frame: never a sequence's, so `clipclique-loc run`
    refuses it as any sequence's map until it is aligned (or forced)."""
    return f"{Path(where).name} (its SLAM frame, not aligned to a sequence)"


def object_ids(map: Map) -> list[int]:
    """The ids a map's landmarks are exported under: the source's ids of an imported map, else the instance ids."""
    ids = map.provenance.get("source_object_ids")
    if isinstance(ids, list) and len(ids) == len(map) and all(isinstance(i, int) for i in ids):
        return ids
    return [int(i) for i in map.instance_ids]


def text_map(map: Map) -> tuple[str, dict[str, str], list[str]]:
    """An OA-SLAM text map of `map`, the classes written as the COCO class that stands for them (the COCO
    table YOLO uses: `monitor` as `tv`), and the classes it cannot hold (no COCO class: left out)."""
    lines, renamed, unwritable = [], {}, set()
    for i, object_id in enumerate(object_ids(map)):
        name = map.class_names[map.class_ids[i]]
        coco = coco_class(name)
        if coco is None:
            unwritable.add(name)
            continue
        if coco != name:
            renamed[name] = coco
        quadric = encode_dual_quadric(map.ellipsoids.centers[i], map.ellipsoids.axes[i], map.ellipsoids.rotations[i])
        numbers = " ".join(f"{v:.8f}" for v in quadric.T.ravel())  # column-major
        lines.append(f"{object_id} {COCO80_INDEX[coco]} {numbers}")
    return "".join(line + "\n" for line in lines), renamed, sorted(unwritable)


def coco_class(name: str) -> str | None:
    """The COCO class that stands for a map class: itself, else the first whose candidates in
    `clipclique.perception.yolo.COCO_TO_MAP` name it (`office chair` -> `chair`), else None."""
    if name in COCO80_INDEX:
        return name
    return next((coco for coco, names in COCO_TO_MAP.items() if name.lower() in names), None)


def landmarks_json(map: Map) -> str:
    """The clipclique JSON landmark list of `map` (docs/import_export.md), exact (floats as JSON's shortest repr,
    which reads back to the same float)."""
    landmarks = []
    for i, object_id in enumerate(object_ids(map)):
        item = {"id": object_id, "class": map.class_names[map.class_ids[i]], "description": map.descriptions[i],
                "center": map.ellipsoids.centers[i].tolist(), "semi_axes": map.ellipsoids.axes[i].tolist(),
                "rotation": map.ellipsoids.rotations[i].tolist(), "instance_id": int(map.instance_ids[i])}
        if map.class_distributions is not None:
            row = map.class_distributions[i]
            item["class_distribution"] = {map.class_names[c]: float(row[c]) for c in np.flatnonzero(row)}
        landmarks.append(item)
    return json.dumps({"format": LANDMARKS_FORMAT, "version": LANDMARKS_VERSION,
                       "frame": map.provenance.get("source", {}).get("name", "unknown"), "landmarks": landmarks},
                      indent=1)
