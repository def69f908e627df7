"""Label sets: which class name an integer category id of another system's file stands for.

OA-SLAM, VOOM and GOReloc write COCO-80 ids (0-based, YOLO's order); MSG-Loc also publishes maps and
detections in LVIS ids (`Detection_assets/lvis.txt`: 1,203 names, the 0-based line being the id).
`--labels coco | lvis | FILE` picks the set; this module owns it for map import and detection files.
COCO results files name their classes themselves (`categories`) and do not use it.

Maps and detections in different sets meet through `LVIS_TO_COCO` (in clipclique.descriptors.lookalikes, which
map alignment matches classes by; LVIS was annotated on COCO's images: each COCO class has LVIS names, `mug`
and `cup`, `computer keyboard` and `keyboard`), and, where a real CLIP is loaded, names no table holds (a
Grounding DINO prompt's `coffee mug`) through their text embeddings (`text_matches`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from clipclique.datasets.base import description_template
from clipclique.descriptors.lookalikes import LVIS_TO_COCO
from clipclique.interop.errors import InteropError
from clipclique.io.safeio import check_text, read_text
from clipclique.perception.yolo import COCO_NAMES
from clipclique.types import Map

if TYPE_CHECKING:
    from clipclique.perception.encoders import Encoder

MAX_LABELS = 10_000  # LVIS holds 1,203; a larger file is not a label list
# A name no table meets is met by text (`text_matches`) only where its nearest map class and that class's nearest
# name are each other, and the nearest stands this far (cosine) above the second: CLIP's text embeddings of any two
# prompts are close (cosines mostly 0.7-0.9), so the gap, not the level, says that one class is meant.
TEXT_MARGIN = 0.05
BUNDLED = ("coco", "lvis")



@dataclass(frozen=True)
class LabelSet:
    """Class names by 0-based id, and where they came from (for messages)."""

    source: str  # "coco", "lvis" or the file's path
    names: tuple[str, ...]

    def name(self, category: int, where: str) -> str:
        """The class name of `category`; InteropError naming `where` and the way out when outside the set."""
        if not 0 <= category < len(self.names):
            hint = "; an LVIS file? pass --labels lvis" if self.source == "coco" and category < 1203 else ""
            raise InteropError(f"{where}: category id {category} is not a {self.source} class id "
                               f"(0..{len(self.names) - 1}){hint}")
        return self.names[category]

    @cached_property
    def duplicates(self) -> dict[str, list[int]]:
        """Names given to more than one id (LVIS has none)."""
        ids: dict[str, list[int]] = {}
        for index, name in enumerate(self.names):
            ids.setdefault(name, []).append(index)
        return {name: found for name, found in ids.items() if len(found) > 1}


COCO = LabelSet("coco", tuple(COCO_NAMES))


def coco_class_of(name: str) -> str | None:
    """The COCO class a class name of any set stands for (itself when COCO's), None when none."""
    if name in COCO_NAMES:
        return name
    return LVIS_TO_COCO.get(name)


def read_label_file(path: Path) -> LabelSet:
    """A names file (one name per line, the 0-based line the id; a final newline optional); InteropError, one
    line naming the file and line, for a blank line, a control character or more than MAX_LABELS names."""
    text = read_text(path, "label file", InteropError, limit=MAX_LABELS * 1024)
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()  # the final newline
    if not lines:
        raise InteropError(f"{path}: an empty label file (one class name per line)")
    if len(lines) > MAX_LABELS:
        raise InteropError(f"{path}: {len(lines)} lines; a label file holds at most {MAX_LABELS:,} class names")
    names = []
    for number, line in enumerate(lines, start=1):
        name = line.removesuffix("\r").strip()
        if not name:
            raise InteropError(f"{path}, line {number}: a blank line; every line names the class of id {number - 1}")
        names.append(check_text(name, f"{path}, line {number}", InteropError))
    return LabelSet(str(path), tuple(names))


def label_set(spec: str | Path | None) -> LabelSet:
    """`--labels`: None or "coco" (COCO-80), "lvis" (the LVIS v1 list MSG-Loc ships), else a names file."""
    if spec is None or str(spec) == "coco":
        return COCO
    if str(spec) == "lvis":
        with resources.as_file(resources.files("clipclique") / "data" / "lvis.txt") as path:
            return LabelSet("lvis", read_label_file(path).names)
    return read_label_file(Path(spec))


def duplicate_note(labels: LabelSet) -> list[str]:
    """The note an import or run prints for names given to several ids (accepted: both ids mean that class)."""
    if not labels.duplicates:
        return []
    name, ids = next(iter(labels.duplicates.items()))
    return [f"{labels.source}: {len(labels.duplicates)} names given to several ids (first {name!r}: ids "
            f"{', '.join(map(str, ids))}); those ids are one class"]


def class_lookup(class_names: list[str]) -> dict[str, int]:
    """Class name (lower case) of any set -> map class id: the map's own names; each COCO class as YOLO's
    detections are mapped (`coco_to_vocabulary`), else to a map class that is an LVIS name of it (`keyboard`
    to `computer keyboard`); each other LVIS name through its COCO class. Names missing here are dropped."""
    from clipclique.perception.yolo import coco_to_vocabulary

    lookup = {name.lower(): index for index, name in enumerate(class_names)}
    by_coco: dict[str, int] = {}
    for coco, mapped in zip(COCO_NAMES, coco_to_vocabulary(class_names)):
        if mapped < 0:
            mapped = next((i for i, name in enumerate(class_names) if coco_class_of(name) == coco), -1)
        if mapped >= 0:
            by_coco[coco.lower()] = int(mapped)
    lookup |= by_coco  # a COCO name goes where YOLO's detections of it go, as before label sets
    for name, coco in LVIS_TO_COCO.items():
        if name.lower() not in lookup and coco.lower() in by_coco:
            lookup[name.lower()] = by_coco[coco.lower()]
    return lookup


def met_by(map: Map, labels: LabelSet) -> tuple[Map, list[str]]:
    """`map` as detections in `labels` see it, and the note saying what changed. An LVIS map (imported with
    `--labels lvis`) names its classes finer than COCO and may split one COCO class over several names (`cup`,
    `mug`, `teacup`); a COCO detection carries one class, so landmarks of the other names would find no
    counterpart, and the look-alike pairs (`lookalikes`, in COCO names) would miss them. Against COCO detections
    each class with a COCO class is named by it, and names of one class are merged. Other maps, and detections
    in the map's own set, are left as they are."""
    if labels.source != "coco" or map.provenance.get("source", {}).get("labels") != "lvis":
        return map, []
    names = [coco_class_of(name) or name for name in map.class_names]
    vocabulary = list(dict.fromkeys(names))
    if vocabulary == map.class_names:
        return map, []
    target = np.array([vocabulary.index(name) for name in names], np.int64)
    distributions = map.class_distributions
    if distributions is not None:
        distributions = np.zeros((len(map), len(vocabulary)))
        np.add.at(distributions.T, target, map.class_distributions.T)
    renamed = [f"{old} -> {new}" for old, new in zip(map.class_names, names) if old != new]
    shown = ", ".join(renamed[:3]) + (", ..." if len(renamed) > 3 else "")
    return (replace(map, class_names=vocabulary, class_ids=target[map.class_ids], class_distributions=distributions),
            [f"LVIS map met by COCO detections: {len(renamed)} of its {len(map.class_names)} classes named by their "
             f"COCO class ({shown}), {len(vocabulary)} classes in all"])


def text_matches(names: list[str], class_names: list[str], encoder: Encoder) -> dict[str, tuple[int, float]]:
    """Detection class names -> (map class id, cosine) by the text embeddings of their prompts
    (`description_template`): a name meets its nearest map class when that class's nearest name is it and the
    nearest stands TEXT_MARGIN above the second. A simulated encoder knows only its scenes' descriptions, so
    nothing is met through one."""
    if not names or not class_names or getattr(encoder, "simulated", True):
        return {}
    embedded = encoder.encode_text([description_template(name) for name in [*names, *class_names]])
    cosine = embedded[:len(names)] @ embedded[len(names):].T
    nearest_class, nearest_name = cosine.argmax(axis=1), cosine.argmax(axis=0)
    ranked = np.sort(cosine, axis=1)
    gap = ranked[:, -1] - (ranked[:, -2] if len(class_names) > 1 else -1.0)
    return {name: (int(nearest_class[row]), float(cosine[row, nearest_class[row]]))
            for row, name in enumerate(names)
            if nearest_name[nearest_class[row]] == row and gap[row] >= TEXT_MARGIN}
