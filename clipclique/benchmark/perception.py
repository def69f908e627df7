"""Perception once: each frame's observations (with their image embeddings), computed once per
(scene, detector, encoder, observation settings, code version) and kept on disk, so that every
configuration of a benchmark reuses them and an interrupted benchmark resumes.

One folder per key, `<cache>/<scene>-<hash>/` with key.json (what the hash stands for) and one
`<frame index>.npz` per frame: plain arrays and a JSON string, read with allow_pickle=False (no
pickle on disk). A file is written beside its place and moved in, so one that exists is whole.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from clipclique.errors import ClipcliqueError
from clipclique.localization.run import Run, Seen
from clipclique.types import Camera, Ellipsoids, Observations, Pose

PACKAGE = Path(__file__).resolve().parents[1]  # clipclique/
CACHE_FORMAT = 2  # what a frame file holds; 2: the detector's scores too (a folder of format 1 is not read)


@dataclass
class Perceived:
    """What localizing and scoring one frame needs, without its images."""

    index: int
    timestamp: float
    name: str
    gt_pose: Pose | None
    observations: Observations | None  # None: the frame has no annotations for the detector to read (left out)
    num_detections: int
    dropped: dict[str, int]
    timings: dict[str, float]  # seconds of the detector, fit and encoder when it was computed


@cache
def code_version() -> str:
    """A hash of the clipclique package (code and shipped data): other code, other observations."""
    digest = hashlib.sha1()
    for path in sorted(p for p in PACKAGE.rglob("*") if p.suffix in (".py", ".csv", ".json") and p.is_file()):
        digest.update(str(path.relative_to(PACKAGE)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def key_of(run: Run) -> dict[str, Any]:
    """Everything the observations of `run`'s frames depend on."""
    return {"sequence": run.sequence.name, "kind": run.sequence.kind, "sequence_frames": len(run.sequence),
            "detector": run.detector.name, "encoder": None if run.encoder is None else run.encoder.name,
            "detector_spec": run.settings.detector, "min_score": run.settings.min_score, "labels": run.settings.labels,
            "strict_detections": run.settings.strict_detections, "map_classes": run.map.class_names,
            "yolo_weights": run.settings.yolo_weights, "seed": run.settings.seed,
            "bag_reading": None if run.settings.bag is None else list(run.settings.bag.image_options()),
            "observations": run.config.to_dict()["observations"], "code": code_version(), "format": CACHE_FORMAT}


def folder_of(cache_root: Path, key: dict[str, Any]) -> Path:
    """The key's folder (created, with its key.json)."""
    text = json.dumps(key, sort_keys=True)
    folder = cache_root / f"{key['sequence']}-{hashlib.sha1(text.encode()).hexdigest()[:16]}"
    if not (folder / "key.json").is_file():
        folder.mkdir(parents=True, exist_ok=True)
        _replace(folder / "key.json", lambda path: path.write_text(text, encoding="utf-8"))
    return folder


def frame_file(folder: Path, index: int) -> Path:
    return folder / f"{index:06d}.npz"


def save_unannotated(path: Path, frame_index: int, timestamp: float, name: str) -> None:
    """A frame the detector cannot read (no instance image): remembered, so it is left out without reading it again."""
    meta = {"index": frame_index, "timestamp": timestamp, "name": name, "unannotated": True}
    _replace(path, lambda partial: np.savez(partial, meta=np.array(json.dumps(meta))))


def save(path: Path, frame_index: int, timestamp: float, name: str, gt_pose: Pose | None, seen: Seen) -> None:
    observations = seen.observations
    arrays = {"centers": observations.ellipsoids.centers, "axes": observations.ellipsoids.axes,
              "rotations": observations.ellipsoids.rotations, "class_ids": observations.class_ids,
              "instance_ids": observations.instance_ids, "detection_index": observations.detection_index}
    optional = {"image_embeddings": observations.image_embeddings, "boxes": observations.boxes,
                "mask_areas": observations.mask_areas, "scores": observations.scores,
                "intrinsics": None if observations.camera is None else observations.camera.intrinsics,
                "gt_pose": None if gt_pose is None else gt_pose.matrix()}
    arrays |= {key: value for key, value in optional.items() if value is not None}
    camera = observations.camera
    meta = {"index": frame_index, "timestamp": timestamp, "name": name, "num_detections": len(seen.detections),
            "dropped": seen.dropped, "timings": seen.timings,
            "camera": None if camera is None else {"width": camera.width, "height": camera.height,
                                                   "max_depth": camera.max_depth}}
    _replace(path, lambda partial: np.savez(partial, meta=np.array(json.dumps(meta)), **arrays))


def load(path: Path) -> Perceived:
    """A cached frame; a damaged file is a one-line error naming it."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
        meta = json.loads(str(arrays.pop("meta")))
        if meta.get("unannotated"):
            return Perceived(int(meta["index"]), float(meta["timestamp"]), str(meta["name"]), None, None, 0, {}, {})
        camera = None if meta["camera"] is None else Camera(arrays["intrinsics"], int(meta["camera"]["width"]),
                                                            int(meta["camera"]["height"]),
                                                            float(meta["camera"]["max_depth"]))
        observations = Observations(Ellipsoids(arrays["centers"], arrays["axes"], arrays["rotations"]),
                                    arrays["class_ids"], arrays.get("image_embeddings"), arrays["instance_ids"],
                                    arrays["detection_index"], arrays.get("boxes"), arrays.get("mask_areas"), camera,
                                    scores=arrays.get("scores"))
        gt_pose = Pose.from_matrix(arrays["gt_pose"]) if "gt_pose" in arrays else None
        return Perceived(int(meta["index"]), float(meta["timestamp"]), str(meta["name"]), gt_pose, observations,
                         int(meta["num_detections"]), dict(meta["dropped"]), dict(meta["timings"]))
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as error:
        raise ClipcliqueError(f"{path}: unreadable perception cache ({type(error).__name__}: {error}); "
                              "remove it to compute the frame again") from None


def _replace(path: Path, write: Any) -> None:
    """Write through `write(partial path)` beside `path`, then move it into place (atomic)."""
    partial = path.with_name(f"{path.name}.{os.getpid()}.partial{path.suffix}")
    try:
        write(partial)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
