"""Readers of other systems' object maps, all into one `ImportedMap` (docs/import_export.md):

- OA-SLAM / VOOM text maps (`map_objects_*.txt`): `<track id> <COCO-80 id> <Q* 16 numbers>` per line;
- Osmap maps by their `.yaml`: GOReloc `.objects` (class counts), OA-SLAM `.mapobjects` +
  `.objecttracks`, VOOM `.Objects` (no class);
- MSG-Loc JSON maps (w-first quaternions, radii, class distributions);
- clipclique's own JSON landmark list (`clipclique-landmarks`, what `export --format json` writes).

Ellipsoids stay in the file's frame (a SLAM map's: its first keyframe's camera); `clipclique.interop.align`
brings them into a dataset's ground-truth frame.
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from clipclique.interop.errors import InteropError
from clipclique.interop.labels import COCO, LabelSet
from clipclique.interop.protowire import Fields, parse_message, repeated_float, repeated_uint, single_uint, submessages
from clipclique.interop.quadric import decode_dual_quadric
from clipclique.io.mapfile import MAX_LANDMARKS
from clipclique.io.safeio import MAX_JSON_BYTES, check_text, read_bytes, read_json, read_text
from clipclique.types import Ellipsoids

LANDMARKS_FORMAT = "clipclique-landmarks"
LANDMARKS_VERSION = 1
MAX_BINARY_BYTES = 256 * 2**20


class MapFormat(enum.StrEnum):
    """The map formats `clipclique-map import` reads (the `--format` values)."""

    OASLAM_TXT = "oaslam-txt"  # OA-SLAM / VOOM text map
    OSMAP = "osmap"  # Osmap .yaml: GOReloc, OA-SLAM or VOOM binary files
    MSGLOC = "msgloc"  # MSG-Loc JSON
    JSON = "json"  # clipclique's landmark list


class SourceSystem(enum.StrEnum):
    """What wrote an imported map."""

    OASLAM_TXT = "oaslam-txt"  # an OA-SLAM / VOOM text map
    GORELOC = "goreloc"
    OASLAM = "oaslam"
    VOOM = "voom"
    MSGLOC = "msgloc"
    JSON = "json"  # clipclique's landmark list


@dataclass
class ImportedMap:
    """Landmarks read from another system's map, before classes are settled and text embedded."""

    source: SourceSystem
    ellipsoids: Ellipsoids  # in the file's frame
    object_ids: list[int]  # the file's object (track, node) ids
    classes: list[str | None]  # COCO (or the file's) class names; None: the file says none (VOOM)
    distributions: list[dict[str, float] | None]  # class -> probability where the file has one
    descriptions: list[str | None] = field(default_factory=list)  # None: the template
    instance_ids: list[int] = field(default_factory=list)  # ground-truth object ids, -1 unknown
    trajectory: Path | None = None  # the keyframe trajectory saved beside the map (TUM text)
    frame: str | None = None  # the sequence whose ground-truth frame the ellipsoids are in, when the file says
    notes: list[str] = field(default_factory=list)  # what a user must know (flipped radii, no classes, ...)

    def __post_init__(self) -> None:
        n = len(self.object_ids)
        self.descriptions = self.descriptions or [None] * n
        self.instance_ids = self.instance_ids or [-1] * n

    def __len__(self) -> int:
        return len(self.object_ids)


OSMAP_BINARIES = (".objects", ".mapobjects", ".objecttracks", ".keyframes", ".mappoints", ".features")


def map_input(path: Path, format: MapFormat | None) -> Path:
    """The file to read for `path`: itself, or the one Osmap `.yaml` of a folder; InteropError, one line saying
    what to pass instead, for another folder or an Osmap binary file (protobuf, named by its `.yaml`)."""
    if path.is_dir():
        yamls = sorted(p for p in path.iterdir() if p.suffix.lower() in (".yaml", ".yml") and p.is_file())
        if len(yamls) == 1 and format in (None, MapFormat.OSMAP):
            return yamls[0]
        held = (f"it holds {len(yamls)} .yaml files "
                f"({', '.join(p.name for p in yamls[:3])})") if yamls else "it holds no .yaml"
        raise InteropError(f"{path}: a folder; pass a map file (map_objects_*.txt, an Osmap "
                           f"map_*.yaml, a .json): {held}")
    if path.suffix.lower() in OSMAP_BINARIES:
        raise InteropError(f"{path}: one of an Osmap map's binary files (protobuf); pass the map_*.yaml that names it")
    return path


def sniff_format(path: Path) -> MapFormat:
    """The format of a map file from its name and first bytes."""
    name = path.name.lower()
    if name.endswith((".yaml", ".yml")):
        return MapFormat.OSMAP
    if name.endswith(".txt"):
        return MapFormat.OASLAM_TXT
    if name.endswith(".json"):
        head = read_bytes(path, MAX_JSON_BYTES, "map file", InteropError)[:4096]
        return MapFormat.JSON if LANDMARKS_FORMAT.encode() in head else MapFormat.MSGLOC
    raise InteropError(f"{path}: cannot tell the map format from the name; pass --format "
                       f"({', '.join(f.value for f in MapFormat)})")


def read_map(path: Path, format: MapFormat | None = None, labels: LabelSet = COCO) -> ImportedMap:
    """The landmarks of a map file of any supported format (sniffed when not given), category ids read in
    `labels` (`--labels`; clipclique's JSON list names its classes and ignores it)."""
    path = map_input(Path(path), format)
    format = format or sniff_format(path)
    reader = {MapFormat.OASLAM_TXT: read_text_map, MapFormat.OSMAP: read_osmap, MapFormat.MSGLOC: read_msgloc,
              MapFormat.JSON: read_landmarks_json}[format]
    imported = reader(path) if format == MapFormat.JSON else reader(path, labels)
    if not 1 <= len(imported) <= MAX_LANDMARKS:
        raise InteropError(f"{path}: {len(imported)} objects; a map holds 1 to {MAX_LANDMARKS}")
    return imported


def _stack(fits: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Ellipsoids:
    if not fits:
        return Ellipsoids.empty()
    centers, axes, rotations = (np.array(column) for column in zip(*fits))
    return Ellipsoids(centers, axes, rotations)


def read_text_map(path: Path, labels: LabelSet = COCO) -> ImportedMap:
    """An OA-SLAM / VOOM `map_objects_*.txt`: `<track id> <category id> <16 numbers of Q*>` per line."""
    fits, ids, classes = [], [], []
    for number, line in enumerate(read_text(path, "map file", InteropError).splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        where = f"{path}, line {number}"
        parts = line.split()
        if len(parts) != 18:
            raise InteropError(f"{where}: expected '<id> <category id> <16 numbers>', got {len(parts)} fields")
        try:
            object_id, category = int(parts[0]), int(parts[1])
            values = np.array([float(p) for p in parts[2:]])
        except ValueError:
            raise InteropError(f"{where}: not numbers: {line[:80]!r}") from None
        classes.append(labels.name(category, where))
        fits.append(decode_dual_quadric(values.reshape(4, 4).T, where))  # column-major
        ids.append(object_id)
    return ImportedMap(SourceSystem.OASLAM_TXT, _stack(fits), ids, classes, [None] * len(ids))


def read_osmap_yaml(path: Path) -> dict[str, str]:
    """The flat `key: value` lines of an OpenCV FileStorage YAML (the `%YAML:1.0` line skipped)."""
    entries = {}
    for line in read_text(path, "Osmap .yaml", InteropError).splitlines():
        match = re.match(r"^([A-Za-z_]\w*)\s*:\s*(.*?)\s*$", line)
        if match and match.group(2):
            entries[match.group(1)] = match.group(2).strip("\"'")
    return entries


def _osmap_file(yaml: Path, entries: dict[str, str], key: str) -> Path:
    name = entries[key]
    if "/" in name or "\\" in name or name in ("", ".", ".."):
        raise InteropError(f"{yaml}: {key} {name!r} should be a file name beside the .yaml")
    return yaml.parent / name


def _array(path: Path, what: str) -> list[Fields]:
    """The elements of an Osmap array message (field 1 repeated)."""
    data = read_bytes(path, MAX_BINARY_BYTES, what, InteropError)
    return submessages(parse_message(data, str(path)), 1, str(path))


def _ellipsoid(element: Fields, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ellipsoid of an Osmap object: field 1 `{1: 16 floats, Q* row-major}`."""
    sub = submessages(element, 1, where)
    if not sub:
        raise InteropError(f"{where}: no ellipsoid (field 1)")
    values = repeated_float(sub[-1], 1, where)
    if len(values) != 16:
        raise InteropError(f"{where}: the ellipsoid holds {len(values)} numbers, not the 16 of a 4x4 dual quadric")
    return decode_dual_quadric(np.array(values).reshape(4, 4), where)


def read_osmap(path: Path, labels: LabelSet = COCO) -> ImportedMap:
    """An Osmap map by its `.yaml`: GOReloc (`objectsFile`), OA-SLAM (`mapobjectsFile` + `objecttracksFile`)
    or VOOM (`ObjectsFile`)."""
    entries = read_osmap_yaml(path)
    trajectory = _trajectory_beside(path)
    if "objectsFile" in entries:
        imported = _read_goreloc(_osmap_file(path, entries, "objectsFile"), labels)
        declared = entries.get("nObjects")
    elif "mapobjectsFile" in entries:
        tracks = _osmap_file(path, entries, "objecttracksFile") if "objecttracksFile" in entries else None
        imported = _read_oaslam(_osmap_file(path, entries, "mapobjectsFile"), tracks, labels)
        declared = entries.get("nMapobjects")
    elif "ObjectsFile" in entries:
        imported = _read_voom(_osmap_file(path, entries, "ObjectsFile"))
        declared = None
    else:
        raise InteropError(f"{path}: an Osmap .yaml without objectsFile, mapobjectsFile or ObjectsFile; "
                           "not an object map")
    if declared is not None and declared.isdigit() and int(declared) != len(imported):
        imported.notes.append(f"{path.name} declares {declared} objects; the object file holds {len(imported)}")
    imported.trajectory = trajectory
    return imported


def _trajectory_beside(yaml: Path) -> Path | None:
    """`keyframes_poses_<name>_tum.txt` (else `camera_poses_<name>_tum.txt`) beside `map_<name>.yaml`."""
    name = yaml.stem.removeprefix("map_")
    for pattern in (f"keyframes_poses_{name}_tum.txt", f"camera_poses_{name}_tum.txt"):
        if (yaml.parent / pattern).is_file():
            return yaml.parent / pattern
    return None


def _read_goreloc(path: Path, labels: LabelSet) -> ImportedMap:
    fits, ids, classes, distributions = [], [], [], []
    for index, element in enumerate(_array(path, "GOReloc objects file")):
        where = f"{path}, object {index}"
        fits.append(_ellipsoid(element, where))
        ids.append(single_uint(element, 2, where, default=index))
        categories, counts = repeated_uint(element, 3, where), repeated_uint(element, 4, where)
        if not categories:
            raise InteropError(f"{where}: no category ids (field 3)")
        if counts and len(counts) != len(categories):
            raise InteropError(f"{where}: {len(counts)} counts for {len(categories)} category ids")
        counts = counts or [1] * len(categories)
        total: dict[str, float] = {}
        for category, count in zip(categories, counts):
            name = labels.name(category, where)
            total[name] = total.get(name, 0.0) + count
        if sum(total.values()) <= 0:
            raise InteropError(f"{where}: every class count is 0")
        classes.append(max(total, key=lambda name: (total[name], -list(total).index(name))))
        distributions.append({name: count / sum(total.values()) for name, count in total.items()})
    return ImportedMap(SourceSystem.GORELOC, _stack(fits), ids, classes, distributions)


def _read_oaslam(path: Path, tracks_path: Path | None, labels: LabelSet) -> ImportedMap:
    categories: dict[int, int] = {}
    if tracks_path is not None:
        for index, track in enumerate(_array(tracks_path, "OA-SLAM object tracks file")):
            where = f"{tracks_path}, track {index}"
            categories[single_uint(track, 1, where)] = single_uint(track, 2, where)
    fits, ids, classes = [], [], []
    for index, element in enumerate(_array(path, "OA-SLAM map objects file")):
        where = f"{path}, object {index}"
        fits.append(_ellipsoid(element, where))
        track = single_uint(element, 2, where)
        if track not in categories:
            raise InteropError(f"{where}: track id {track} has no entry in "
                               f"{tracks_path or 'the object tracks file (objecttracksFile missing from the .yaml)'}")
        ids.append(track)
        classes.append(labels.name(categories[track], where))
    return ImportedMap(SourceSystem.OASLAM, _stack(fits), ids, classes, [None] * len(ids))


def _read_voom(path: Path) -> ImportedMap:
    fits, ids = [], []
    for index, element in enumerate(_array(path, "VOOM objects file")):
        where = f"{path}, object {index}"
        fits.append(_ellipsoid(element, where))
        ids.append(single_uint(element, 2, where, default=index))
    return ImportedMap(SourceSystem.VOOM, _stack(fits), ids, [None] * len(ids), [None] * len(ids),
                       notes=["a VOOM map holds no classes: give them with --objects objects.csv "
                              "(id,class,description)"])


def _numbers(value: object, count: int, where: str) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == count
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise InteropError(f"{where} should be a list of {count} numbers, got {str(value)[:60]}")
    array = np.array(value, dtype=np.float64)
    if not np.isfinite(array).all():
        raise InteropError(f"{where} holds non-finite numbers")
    return array


def _label_distribution(value: object, where: str, with_colour: bool, labels: LabelSet) -> dict[str, float]:
    """MSG-Loc's `{"66.0": [p, ...]}` as {class name in `labels`: p}."""
    if not isinstance(value, dict):
        raise InteropError(f"{where} should be an object keyed by class id")
    out: dict[str, float] = {}
    for key, entry in value.items():
        try:
            number = float(key)
        except ValueError:
            raise InteropError(f"{where}: key {key!r} is not a class id") from None
        if not number.is_integer():
            raise InteropError(f"{where}: key {key!r} is not a whole class id")
        if not (isinstance(entry, list) and entry and isinstance(entry[0], (int, float))
                and not isinstance(entry[0], bool)
                and math.isfinite(entry[0]) and 0 <= entry[0] <= 1 + 1e-6):
            raise InteropError(f"{where}[{key!r}] should start with a probability in [0, 1]")
        if with_colour and len(entry) > 1 and not (isinstance(entry[1], list) and len(entry[1]) == 3):
            raise InteropError(f"{where}[{key!r}]: the second entry should be an [r, g, b] colour")
        name = labels.name(int(number), where)
        out[name] = out.get(name, 0.0) + float(entry[0])
    return out


def read_msgloc(path: Path, labels: LabelSet = COCO) -> ImportedMap:
    """An MSG-Loc JSON map: nodes with w-first quaternions, radii (absolute values taken), class labels."""
    data = read_json(path, "MSG-Loc map", InteropError)
    if not isinstance(data, dict) or not isinstance(data.get("nodes"), list):
        raise InteropError(f"{path}: an MSG-Loc map is a JSON object with a 'nodes' list")
    fits, ids, classes, distributions = [], [], [], []
    flipped = 0
    for index, node in enumerate(data["nodes"]):
        where = f"{path}, node {index}"
        if not isinstance(node, dict):
            raise InteropError(f"{where}: not an object")
        node_id = node.get("id")
        if not isinstance(node_id, int) or isinstance(node_id, bool) or not 0 <= node_id < 2**64:
            raise InteropError(f"{where}: id {node_id!r} is not an unsigned 64-bit integer")
        center = _numbers(node.get("translation"), 3, f"{where}: translation")
        w, x, y, z = _numbers(node.get("orientation"), 4, f"{where}: orientation")
        if abs(np.linalg.norm([w, x, y, z]) - 1) > 1e-3:
            raise InteropError(f"{where}: orientation [w, x, y, z] is not a unit quaternion")
        radii = _numbers(node.get("radii"), 3, f"{where}: radii")
        flipped += int((radii < 0).any())
        if (np.abs(radii) <= 0).any():
            raise InteropError(f"{where}: a radius is 0")
        if "baseline_label" in node:
            distribution = _label_distribution(node["baseline_label"], f"{where}: baseline_label", True, labels)
        elif "msgloc_label" in node:
            distribution = _label_distribution(node["msgloc_label"], f"{where}: msgloc_label", False, labels)
        else:
            raise InteropError(f"{where}: no baseline_label or msgloc_label, so no class")
        total = sum(distribution.values())
        if total <= 0:
            raise InteropError(f"{where}: every class probability is 0")
        fits.append((center, np.abs(radii), Rotation.from_quat([x, y, z, w]).as_matrix()))
        ids.append(node_id)
        classes.append(max(distribution, key=distribution.get))
        distributions.append({name: p / total for name, p in distribution.items()})
    notes = [f"{flipped} nodes had negative radii: their absolute values taken"] if flipped else []
    return ImportedMap(SourceSystem.MSGLOC, _stack(fits), ids, classes, distributions, notes=notes)


def read_landmarks_json(path: Path) -> ImportedMap:
    """clipclique's JSON landmark list (docs/import_export.md): what `clipclique-map export --format json` writes."""
    data = read_json(path, "landmark list", InteropError)
    if not isinstance(data, dict) or data.get("format") != LANDMARKS_FORMAT:
        raise InteropError(f"{path}: not a clipclique landmark list (\"format\": \"{LANDMARKS_FORMAT}\" missing)")
    if data.get("version") != LANDMARKS_VERSION:
        raise InteropError(f"{path}: landmark list version {data.get('version')!r} not supported (this reads "
                           f"{LANDMARKS_VERSION})")
    if not isinstance(data.get("landmarks"), list):
        raise InteropError(f"{path}: 'landmarks' should be a list")
    fits, ids, classes, distributions, descriptions, instances = [], [], [], [], [], []
    for index, item in enumerate(data["landmarks"]):
        where = f"{path}, landmark {index}"
        if not isinstance(item, dict):
            raise InteropError(f"{where}: not an object")
        rotation = _rotation(item.get("rotation"), where)
        axes = _numbers(item.get("semi_axes"), 3, f"{where}: semi_axes")
        if (axes <= 0).any():
            raise InteropError(f"{where}: semi_axes must be positive")
        fits.append((_numbers(item.get("center"), 3, f"{where}: center"), axes, rotation))
        object_id, instance = item.get("id", index), item.get("instance_id", -1)
        for key, value in (("id", object_id), ("instance_id", instance)):
            if not isinstance(value, int) or isinstance(value, bool):
                raise InteropError(f"{where}: {key} {value!r} is not an integer")
        ids.append(object_id)
        instances.append(instance)
        classes.append(check_text(item.get("class"), f"{where}: class", InteropError).strip() or None)
        description = item.get("description")
        descriptions.append(None if description is None
                            else check_text(description, f"{where}: description", InteropError))
        distributions.append(_distribution(item.get("class_distribution"), where))
    frame = data.get("frame")
    frame = None if frame in (None, "unknown") else check_text(frame, f"{path}: frame", InteropError)
    return ImportedMap(SourceSystem.JSON, _stack(fits), ids, classes, distributions, descriptions, instances,
                       frame=frame)


def _rotation(value: object, where: str) -> np.ndarray:
    rows = value if isinstance(value, list) and len(value) == 3 else None
    if rows is None:
        raise InteropError(f"{where}: rotation should be 3 rows of 3 numbers")
    matrix = np.array([_numbers(row, 3, f"{where}: rotation row") for row in rows])
    if not np.allclose(matrix.T @ matrix, np.eye(3), atol=1e-6) or np.linalg.det(matrix) < 0:
        raise InteropError(f"{where}: rotation is not a rotation matrix (orthonormal, determinant +1)")
    return matrix


def _distribution(value: object, where: str) -> dict[str, float] | None:
    if value is None:
        return None
    if not isinstance(value, dict) or not value:
        raise InteropError(f"{where}: class_distribution should be an object {{class: probability}}")
    out = {}
    for name, p in value.items():
        check_text(name, f"{where}: class_distribution class", InteropError)
        if not isinstance(p, (int, float)) or isinstance(p, bool) or not 0 <= p <= 1:
            raise InteropError(f"{where}: class_distribution[{name!r}] = {p!r} is not a probability")
        out[name] = float(p)
    if abs(sum(out.values()) - 1) > 1e-3:
        raise InteropError(f"{where}: class_distribution sums to {sum(out.values()):.3g}, not 1")
    return out
