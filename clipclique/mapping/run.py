"""The runners of `clipclique-map build` (open the scene, build the map, write it and its recording),
`import` (read another system's map, align it, write it and its recording) and `export`.

What the CLI, tools/demo.py and the benchmark call; it prints nothing (clipclique.mapping.tables does).
The map and its recording are staged and appear together (clipclique.io.outputs).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clipclique.backends import load_encoder
from clipclique.datasets import scene_name
from clipclique.errors import ClipcliqueError
from clipclique.interop.commands import (
    AlignmentRequest,
    ExportFormat,
    ImportReport,
    default_export_path,
    default_import_path,
    export_text,
    import_map,
    replaced_source,
)
from clipclique.interop.errors import InteropError
from clipclique.interop.labels import label_set
from clipclique.interop.maps import MapFormat, map_input
from clipclique.io.mapfile import load_map, save_map
from clipclique.io.outputs import Staging, map_file
from clipclique.mapping.build import BuildReport, Progress, build_map
from clipclique.resolve import first_use_notice, open_scene
from clipclique.types import Map

Bars = Callable[[str], Progress]  # a stage's description -> its progress callback
GENERATING = "generating the {scene} data (first use)"
FITTING = "fitting ellipsoids"
PROBING = "--encoder auto: looking for CLIP weights (ViT-L-14/openai; a few seconds)"


@dataclass
class Built:
    """A finished build: the map, how each instance fared, and the files written."""

    map: Map
    report: BuildReport
    encoder_spec: str  # as asked or defaulted (auto, simulated, ...): the summary says why there is no encoder
    out: Path
    recording: Path | None  # None with rrd=False
    stale: Path | None  # an earlier map's recording, left in place (--no-rrd), that shows other landmarks


def run_build(scene: str, data_root: Path | None = None, out: Path | None = None, encoder_spec: str | None = None,
              rrd: bool = True, bars: Bars | None = None, say: Callable[[str], None] | None = None) -> Built:
    """Open the scene (generating a demo scene on first use), fit the landmarks, embed the descriptions,
    write the map (and .rrd) to `out`, default outputs/maps/<SCENE>.map.npz (the name clipclique-loc looks up).
    `bars` gives each stage a progress callback (generating the demo data, fitting); `say` is told, before
    they start, what the slow first steps are (generating a scene, probing for CLIP weights)."""
    started = time.perf_counter()
    out = out or map_file(scene_name(scene))
    recording = out.with_name(out.name.removesuffix(".npz") + ".rrd")
    with Staging() as staging:
        staged_map = staging.path(out)  # a folder in the way is refused before the work
        staged_recording = staging.path(recording) if rrd else None
        if say and (notice := first_use_notice(scene, data_root)):
            say(notice)
        sequence = open_scene(scene, data_root, bars and bars(GENERATING.format(scene=scene)))
        spec = encoder_spec or ("simulated" if sequence.synthetic else "auto")
        if say and spec == "auto":
            say(PROBING)
        map, report = build_map(sequence, load_encoder(spec), progress=bars and bars(FITTING))
        save_map(map, staged_map)
        if staged_recording is not None:
            from clipclique.viz import write_map_recording  # rerun is imported only when a build records

            cloud = sequence.scene_cloud()
            write_map_recording(staged_recording, map, *(cloud or (None, None)),
                                description=describe(map, sequence.name))
        stale = recording if staged_recording is None and recording.is_file() and not shows_map(out, map) else None
        staging.commit()
    report.timings["total"] = time.perf_counter() - started
    return Built(map, report, spec, out, recording if rrd else None, stale)


def shows_map(earlier: Path, map: Map) -> bool:
    """Whether the map file `earlier` (about to be replaced), and so the recording made with it, holds the
    same landmarks as `map`; False when it cannot be read."""
    try:
        old = load_map(earlier)
    except (ClipcliqueError, OSError):
        return False
    arrays = ("centers", "axes", "rotations")
    return (all(np.array_equal(getattr(old.ellipsoids, a), getattr(map.ellipsoids, a)) for a in arrays)
            and np.array_equal(old.class_ids, map.class_ids) and np.array_equal(old.instance_ids, map.instance_ids)
            and (old.class_names, old.descriptions, old.encoder) == (map.class_names, map.descriptions, map.encoder))


def describe(map: Map, scene: str) -> str:
    """The recording's text document: what the map is and what made it (an imported map: which file, which
    system); classes counted only where they hold a landmark."""
    source = map.provenance.get("source", {})
    simulated = (" (simulated CLIP: a stand-in for real CLIP on synthetic data)"
                 if map.provenance.get("encoder_simulated") else "")
    if source.get("kind") == "import":
        origin = f"imported from {source.get('file', '?')} ({source.get('format', '?')})"
    else:
        origin = f"from a {source.get('kind', '?')} scene{' (synthetic demo)' if source.get('synthetic') else ''}"
    structure = map.provenance.get("structure_left_out", [])
    return (
        f"# Map of {scene}\n\n{len(map)} landmarks, {len(set(map.class_ids.tolist()))} classes, {origin}.\n\n"
        f"Text embeddings: {map.encoder}{simulated}."
        + (f"\n\nLeft out as structure: {', '.join(structure)}." if structure else "")
    )


@dataclass
class Imported:
    """A finished import: what was read, how it was aligned, and the files written."""

    path: Path  # the file imported
    report: ImportReport
    encoder_spec: str
    out: Path
    recording: Path | None  # None with rrd=False
    seconds: float


def run_import(path: Path, format: MapFormat | None = None, objects: Path | None = None, align_to: str | None = None,
               groundtruth: Path | None = None, request: AlignmentRequest = AlignmentRequest(),
               data_root: Path | None = None, out: Path | None = None, encoder_spec: str = "auto",
               rrd: bool = True, labels: str | None = None, force: bool = False) -> Imported:
    """Read another system's map, align it to `align_to`'s groundtruth.txt (or `groundtruth`) when given, embed
    its descriptions, write the map (and .rrd) to `out`, default outputs/maps/<file stem>.map.npz; `labels`
    (`--labels`: coco, lvis or a names file) names the file's category ids. A map at `out` from another source
    is refused unless `force` (two systems' Osmap maps of one sequence are both `map_<name>.yaml`)."""
    started = time.perf_counter()
    if align_to is not None and groundtruth is not None:
        raise InteropError("give --align-to or --groundtruth, not both")
    if align_to is not None:
        sequence = open_scene(align_to, data_root)
        if sequence.kind != "tum":
            raise InteropError(f"--align-to {align_to}: a {sequence.kind} scene; alignment needs a TUM sequence's "
                               "groundtruth.txt (or --groundtruth FILE)")
        request = dataclasses.replace(request, groundtruth=sequence.root / "groundtruth.txt",
                                      sequence_name=sequence.name)
    elif groundtruth is not None:
        request = dataclasses.replace(request, groundtruth=groundtruth)
    path = map_input(path, format)  # a folder's one Osmap .yaml
    out = out or default_import_path(path)
    recording = out.with_name(out.name.removesuffix(".npz") + ".rrd")
    with Staging() as staging:
        staged_map = staging.path(out)
        staged_recording = staging.path(recording) if rrd else None
        report = import_map(path, format, objects, request, load_encoder(encoder_spec), label_set(labels))
        if not force and (held := replaced_source(out, report.map)):
            raise InteropError(f"{out} holds {held}; importing {path} would replace it: pass --out FILE, "
                               "or --force to replace it")
        save_map(report.map, staged_map)
        if staged_recording is not None:
            from clipclique.viz import write_map_recording

            write_map_recording(staged_recording, report.map, None, None,
                                description=describe(report.map, report.sequence_name or path.name))
        staging.commit()
    return Imported(path, report, encoder_spec, out, recording if rrd else None, time.perf_counter() - started)


@dataclass
class Exported:
    out: Path
    written: int  # landmarks written
    renamed: dict[str, str]  # map class -> the COCO class it was written as
    unwritable: list[str]  # classes left out
    left_out: int  # landmarks of those classes


def run_export(map_path: Path, format: ExportFormat, out: Path | None = None) -> Exported:
    """Write a map as an OA-SLAM text map or a JSON landmark list (staged), default beside the map."""
    map = load_map(map_path)
    text, renamed, unwritable = export_text(map, format)
    out = out or default_export_path(map_path, format)
    with Staging() as staging:
        staged = staging.path(out)
        try:
            staged.write_text(text)
        except OSError as error:
            raise InteropError(f"{out}: cannot write ({error.strerror or error})") from None
        staging.commit()
    left_out = sum(map.class_names[c] in unwritable for c in map.class_ids)
    return Exported(out, len(map) - left_out, renamed, unwritable, left_out)
