"""The work behind `clipclique-map import` and `clipclique-map export`, as library calls: read, settle
classes, align, embed; the text an export writes. The runner (clipclique.mapping.run) opens sequences and writes."""

from __future__ import annotations

import enum
import hashlib
from dataclasses import dataclass
from pathlib import Path

from clipclique.errors import ClipcliqueError
from clipclique.interop.align import Alignment, AlignmentLimits, align_trajectory, aligned_map
from clipclique.interop.convert import landmarks_json, read_objects, text_map, to_map
from clipclique.interop.errors import InteropError
from clipclique.interop.labels import COCO, LabelSet, duplicate_note
from clipclique.interop.maps import MAX_BINARY_BYTES, ImportedMap, MapFormat, map_input, read_map
from clipclique.io.mapfile import load_map
from clipclique.io.outputs import map_file
from clipclique.io.safeio import read_bytes
from clipclique.perception.encoders import Encoder
from clipclique.types import Map


class ExportFormat(enum.StrEnum):
    """The `--format` values of `clipclique-map export`."""

    OASLAM_TXT = "oaslam-txt"
    JSON = "json"


@dataclass
class AlignmentRequest:
    """Where the ground truth and the keyframe trajectory come from (the runner resolves --align-to)."""

    groundtruth: Path | None = None  # a TUM groundtruth.txt; None: no alignment
    sequence_name: str | None = None  # the sequence it belongs to, recorded as the map's source
    trajectory: Path | None = None  # --trajectory, else the one saved beside an Osmap map
    with_scale: bool = False  # --scale: monocular maps
    limits: AlignmentLimits = AlignmentLimits()


@dataclass
class ImportReport:
    map: Map
    imported: ImportedMap
    alignment: Alignment | None
    sequence_name: str | None  # the sequence the map is now in the frame of


def import_map(path: Path, format: MapFormat | None, objects: Path | None, request: AlignmentRequest,
               encoder: Encoder | None, labels: LabelSet = COCO) -> ImportReport:
    """The clipclique map of another system's map file (category ids in `labels`), aligned to ground truth when
    asked."""
    path = map_input(path, format)
    imported = read_map(path, format, labels)
    imported.notes += duplicate_note(labels)
    digest = hashlib.sha256(read_bytes(path, MAX_BINARY_BYTES, "map file", InteropError)).hexdigest()
    map = to_map(imported, str(path), read_objects(objects) if objects else None, encoder, digest, labels.source)
    if request.groundtruth is None:
        return ImportReport(map, imported, None, imported.frame)
    trajectory = request.trajectory or imported.trajectory
    if trajectory is None:
        raise InteropError(f"{path}: no keyframe trajectory beside this map (keyframes_poses_<name>_tum.txt); "
                           "pass --trajectory FILE")
    alignment = align_trajectory(trajectory, request.groundtruth, request.with_scale, request.limits)
    map = aligned_map(map, alignment, request.sequence_name or f"{request.groundtruth.name} frame",
                      alignment.record(trajectory, request.groundtruth))
    return ImportReport(map, imported, alignment, request.sequence_name)


def replaced_source(out: Path, map: Map) -> str | None:
    """What an existing `out` holds when importing `map` would replace another source's map (None: nothing there, or
    an import of the same input, by its sha256, which may be replaced)."""
    if not out.exists():
        return None
    try:
        source = load_map(out).provenance.get("source", {})
    except (ClipcliqueError, OSError):
        return "a file that is not a readable map"
    if source.get("kind") == "import" and source.get("sha256") == map.provenance["source"].get("sha256"):
        return None
    if source.get("kind") == "import":
        return f"a map imported from {source.get('file', '?')}"
    return f"a map of {source.get('name', '?')} ({source.get('kind', '?')})"


def default_import_path(path: Path) -> Path:
    """outputs/maps/<file stem>.map.npz: never the name of a built map, which an import must not replace unasked."""
    return map_file(path.stem)


def export_text(map: Map, format: ExportFormat) -> tuple[str, dict[str, str], list[str]]:
    """The exported file's text, the classes written as another COCO class, and those it could not hold."""
    if format == ExportFormat.OASLAM_TXT:
        text, renamed, unwritable = text_map(map)
        if not text:
            raise InteropError(f"no landmark of this map has a COCO class ({', '.join(unwritable)}); "
                               "an OA-SLAM text map can hold COCO classes only (use --format json)")
        return text, renamed, unwritable
    if format == ExportFormat.JSON:
        return landmarks_json(map), {}, []
    raise InteropError(f"--format {format!r}: choose {' or '.join(ExportFormat)}")


def default_export_path(map_path: Path, format: ExportFormat) -> Path:
    """Beside the map: map_objects_<name>.txt (OA-SLAM's naming) or <name>.landmarks.json."""
    name = map_path.name.removesuffix(".npz").removesuffix(".map")
    return map_path.with_name(f"map_objects_{name}.txt" if format == ExportFormat.OASLAM_TXT
                              else f"{name}.landmarks.json")
