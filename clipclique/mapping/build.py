"""Scene objects -> ellipsoid landmarks -> Map: the work behind `clipclique-map build`.

Each object instance of a scene (its world points) becomes one landmark: statistical outlier
removal, then open3d's PCA oriented box, then the inscribed ellipsoid (clipclique.perception.ellipsoids).
Structure (walls, floors, ceilings) is left out; instances too small or degenerate to fit are
skipped and counted by reason, never dropped silently. Landmarks stay in the dataset's world
frame. Text embeddings of the descriptions come from the encoder, when there is one.
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np

from clipclique.config import FitParams
from clipclique.datasets import STRUCTURE_CLASSES, Instance, Sequence, is_structure
from clipclique.descriptors.graph import semantic_graph
from clipclique.errors import DatasetError
from clipclique.perception.ellipsoids import fit_ellipsoid, stack_ellipsoids
from clipclique.perception.encoders import Encoder
from clipclique.types import Map
from clipclique.version import __version__

Progress = Callable[[int, int], None]


@dataclass
class BuildReport:
    """What happened to every instance, for the summary a user reads."""

    landmarks_per_class: Counter = field(default_factory=Counter)
    structure: Counter = field(default_factory=Counter)  # class -> instances left out as structure
    skipped: dict[str, list[str]] = field(default_factory=dict)  # reason -> ["chair #12", ...]
    timings: dict[str, float] = field(default_factory=dict)  # seconds: "read", "fit", "encode"
    encoder: str = "none"
    notes: list[str] = field(default_factory=list)  # facts about the input the user must see (frames without a pose)

    def skip(self, reason: str, instance: Instance) -> None:
        self.skipped.setdefault(reason, []).append(f"{instance.class_name} #{instance.instance_id}")


def skip_reason(instance: Instance, params: FitParams) -> str:
    """Why fit_ellipsoid gave no ellipsoid for this instance."""
    finite = int(np.isfinite(instance.points).all(axis=1).sum()) if len(instance.points) else 0
    if finite < params.min_points:
        return f"fewer than {params.min_points} points"
    return f"degenerate (a semi-axis under {params.min_axis * 100:g} cm) or too few points after outlier removal"


def fit_landmarks(
    instances: list[Instance], params: FitParams, report: BuildReport, progress: Progress | None = None
) -> tuple[list[Instance], list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """The instances that became landmarks and their (center, axes, rotation) fits."""
    kept, fits = [], []
    for done, instance in enumerate(instances, start=1):
        if is_structure(instance.class_name):
            report.structure[instance.class_name] += 1
        elif (fit := fit_ellipsoid(instance.points, params)) is None:
            report.skip(skip_reason(instance, params), instance)
        else:
            kept.append(instance)
            fits.append(fit)
        if progress:
            progress(done, len(instances))
    return kept, fits


def build_map(
    sequence: Sequence,
    encoder: Encoder | None,
    params: FitParams = FitParams(),
    progress: Progress | None = None,
) -> tuple[Map, BuildReport]:
    """The landmark map of a scene and the report of how each instance fared.

    A scene none of whose objects becomes a landmark is a DatasetError saying why (a map of
    nothing would localize nothing, and with an encoder it would not even be a valid map file).
    """
    report = BuildReport(encoder=encoder.name if encoder else "none")
    start = time.perf_counter()
    instances = sequence.instances()
    report.timings["read"] = time.perf_counter() - start

    start = time.perf_counter()
    kept, fits = fit_landmarks(instances, params, report, progress)
    report.timings["fit"] = time.perf_counter() - start
    if gap := sequence.missing_poses():
        report.notes.append(f"{gap}; their annotations are not in the map")
    if not kept:
        cause = f"; {gap}" if gap else ""
        raise DatasetError(f"{sequence.root}: no landmarks to map: {_empty_map_reason(instances, report)}{cause}")
    class_names = sorted({i.class_name for i in kept})
    report.landmarks_per_class.update(i.class_name for i in kept)

    descriptions = [i.description for i in kept]
    embeddings = None
    if encoder is not None:
        start = time.perf_counter()
        embeddings = np.asarray(encoder.encode_text(descriptions), dtype=np.float32)
        report.timings["encode"] = time.perf_counter() - start

    provenance = {
        "source": {"name": sequence.name, "kind": sequence.kind, "root": str(sequence.root),
                   "synthetic": sequence.synthetic},
        "parameters": dataclasses.asdict(params),
        "structure_left_out": sorted(STRUCTURE_CLASSES),
        "skipped": {reason: len(items) for reason, items in report.skipped.items()},
        "encoder_simulated": bool(encoder is not None and getattr(encoder, "simulated", False)),
        "tool": "clipclique-map",
        "version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    map = Map(
        ellipsoids=stack_ellipsoids(fits),
        class_ids=np.array([class_names.index(i.class_name) for i in kept], dtype=np.int64),
        class_names=class_names,
        descriptions=descriptions,
        instance_ids=np.array([i.instance_id for i in kept], dtype=np.int64),
        text_embeddings=embeddings,
        encoder=report.encoder,
        provenance=provenance,
    )
    return map, report


def _empty_map_reason(instances: list[Instance], report: BuildReport) -> str:
    """Why no instance of a scene became a landmark, for the error a user reads."""
    if not instances:
        return ("the scene has no annotated objects (a TUM sequence needs annotations/objects.csv and "
                "annotations/instances/)")
    parts = [f"{sum(report.structure.values())} left out as structure"] if report.structure else []
    parts += [f"{len(items)} skipped, {reason}" for reason, items in report.skipped.items()]
    return f"none of its {len(instances)} objects could be fitted ({'; '.join(parts)})"


def degree_histogram(map: Map, d_adj: float) -> np.ndarray:
    """Landmarks per semantic-graph degree (index = degree) at `d_adj`: index 0 counts the isolated ones,
    whose Semantic Histograms are empty."""
    return np.bincount(np.diff(semantic_graph(map.ellipsoids.centers, d_adj).indptr), minlength=1)
