"""How much a scene looks like real data: the statistics of docs/REAL_SCENES.md, measured.

    .venv/bin/python tools/scene_stats.py demo_apartment
    .venv/bin/python tools/scene_stats.py demo_desk [--detector simulated-yolo] [--frames 40]
    .venv/bin/python tools/scene_stats.py demo_apartment demo_desk demo_clutter --readme README.md
        (what `make docs` runs)
    .venv/bin/python tools/scene_stats.py --results outputs/loc/demo_sparse/clipclique/results.json
        (where a run loses its frames, beside the real desk's: clipclique.benchmark.failure_profile)

Everything goes through the project's own code: the map from `clipclique.mapping.build.build_map`, the frames
from the dataset reader, the detections from `clipclique.backends`, the observed ellipsoids from
`clipclique.perception.observations.extract_observations`. Geometry (observations per frame, isolated
observations, centre offsets) is measured with ground-truth instances; the detector's faults
(misses, false positives, confusions) with the scene's default detector or `--detector`, against
ground truth: a detection hits the mapped object that covers at least half its mask.
Prints each figure beside the real scan's (REAL_SCENES.md).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clipclique.backends import make_detector
from clipclique.benchmark import failure_profile
from clipclique.benchmark.failure_profile import hit_objects
from clipclique.benchmark.report import update_readme
from clipclique.config import GraphConfig
from clipclique.datasets import Sequence
from clipclique.descriptors.graph import semantic_graph
from clipclique.exits import user_errors
from clipclique.mapping.build import build_map
from clipclique.perception.detectors import InstanceDetector
from clipclique.perception.observations import ObservationParams, extract_observations
from clipclique.resolve import default_detector, open_scene
from clipclique.types import Map

NEAR_M = 3.5  # "objects in view within 3.5 m" (REAL_SCENES.md, desk)
FAR_OFFSET_M = 0.3  # d_comp: offsets beyond it fail the rigid distance test
DETECTOR_FAULTS = ("miss_rate", "false_positive_share", "confusion_share")  # rows that are 0 for ground truth

# REAL_SCENES.md's figures, by the scene layout they describe; None where the real data has none.
REAL = {
    "scannet": {
        "objects": "45", "classes": "30", "extent_m": "7.3 x 7.8 x 2.1", "degree_histogram": "21, 7, 6, 6, 3, 1, 1",
        "isolated_objects": "47%", "degree_median_max": None, "observations_per_frame": "3 to 17, median 9",
        "observations_near": None, "isolated_observations": "47%", "offset_percentiles": "0.18 / 0.38 / 0.80 / 1.09",
        "offsets_far": "32%", "detections_per_frame": None, "miss_rate": None, "false_positive_share": None,
        "confusion_share": None, "duplicates_per_frame": None, "frames_three_hit": None,
    },
    "tum": {
        "objects": "47", "classes": "19", "extent_m": "5.5 x 3.4 x 1.0", "degree_histogram": None,
        "isolated_objects": None, "degree_median_max": "17 / 30", "observations_per_frame": None,
        "observations_near": "about 26", "isolated_observations": None, "offset_percentiles": None, "offsets_far": None,
        "detections_per_frame": "about 10", "miss_rate": "about 70%", "false_positive_share": "21%",
        "confusion_share": "34%", "duplicates_per_frame": "some", "frames_three_hit": "96%",
    },
}


@dataclass
class SceneStats:
    """The measured statistics of one scene (fractions in 0..1, distances in metres)."""

    objects: int
    classes: int
    extent: np.ndarray  # (3,) of the mapped objects' points
    degrees: np.ndarray  # (N,) semantic-graph degree of each landmark at d_adj
    observations: np.ndarray  # (F,) ground-truth observations per frame
    observations_near: np.ndarray  # (F,) ... of them within NEAR_M of the camera
    isolated_observations: float  # share of all observations with no neighbour in their frame's query graph
    offsets: np.ndarray  # (O,) observed centre (moved to the world) vs its landmark's centre
    detector: str
    in_view: int = 0  # mapped objects seen (ground truth) in the measured frames, summed
    hit_objects: int = 0  # ... of them detected
    detections: int = 0
    false_positives: int = 0
    confusions: Counter = field(default_factory=Counter)  # (true class, detected class) -> count
    duplicates: int = 0  # detections of an object another detection of the frame already hits
    frames_three_hit: int = 0  # frames whose detections hit three or more distinct mapped objects

    @property
    def hits(self) -> int:
        return self.detections - self.false_positives

    @property
    def miss_rate(self) -> float:
        return 1 - self.hit_objects / max(self.in_view, 1)

    @property
    def false_positive_share(self) -> float:
        return self.false_positives / max(self.detections, 1)

    @property
    def confusion_share(self) -> float:
        return sum(self.confusions.values()) / max(self.hits, 1)


def landmark_extent(sequence: Sequence, map: Map) -> np.ndarray:
    """(3,) size of the axis-aligned box holding the points of every mapped object."""
    points = np.concatenate([i.points for i in sequence.instances() if i.instance_id in set(map.instance_ids.tolist())])
    points = points[np.isfinite(points).all(axis=1)]
    return points.max(axis=0) - points.min(axis=0)


def measure(sequence: Sequence, detector_kind: str | None = None, frames: int | None = None,
            d_adj: float = GraphConfig().d_adj) -> SceneStats:
    """The statistics of `sequence` over `frames` frames spread over it (all by default)."""
    map, _ = build_map(sequence, encoder=None)
    detector_kind = detector_kind or default_detector(sequence)
    truth = InstanceDetector(sequence.object_classes(), map.class_names)
    detector = make_detector(detector_kind, sequence.object_classes(), map.class_names)
    centre_of = dict(zip(map.instance_ids.tolist(), map.ellipsoids.centers))
    class_of = dict(zip(map.instance_ids.tolist(), map.class_ids.tolist()))
    mapped = map.instance_ids
    params = ObservationParams()
    stats = SceneStats(len(map), len(map.class_names), landmark_extent(sequence, map),
                       np.diff(semantic_graph(map.ellipsoids.centers, d_adj).indptr), np.zeros(0, int),
                       np.zeros(0, int), 0.0, np.zeros(0), detector.name)
    counts, near, isolated, offsets = [], [], [], []
    step = max(1, len(sequence) // frames) if frames else 1
    for i in range(0, len(sequence), step)[:frames]:
        frame = sequence[i]
        true = truth.detect(frame)
        observations = extract_observations(frame, true).observations
        centers = observations.ellipsoids.centers
        counts.append(len(observations))
        near.append(int((np.linalg.norm(centers, axis=1) <= NEAR_M).sum()))
        isolated.extend(np.diff(semantic_graph(centers, d_adj).indptr) == 0)
        known = np.isin(observations.instance_ids, mapped)
        landmarks = np.array([centre_of[int(j)] for j in observations.instance_ids[known]]).reshape(-1, 3)
        offsets.extend(np.linalg.norm(frame.pose.apply(centers[known]) - landmarks, axis=1))
        in_view = {int(j) for j, pixels in zip(true.instance_ids, true.masks.sum(axis=(1, 2)))
                   if j in centre_of and pixels >= params.min_mask_pixels}
        detections = detector.detect(frame)
        hits = hit_objects(frame, detections, mapped)
        stats.in_view += len(in_view)
        stats.hit_objects += len(in_view & set(hits.tolist()))
        stats.detections += len(detections)
        stats.false_positives += int((hits == 0).sum())
        distinct = set(hits[hits > 0].tolist())
        stats.duplicates += int((hits > 0).sum()) - len(distinct)
        stats.frames_three_hit += len(distinct) >= 3
        for obj, detected in zip(hits, detections.class_ids):
            if obj and class_of[int(obj)] != detected:
                stats.confusions[(map.class_names[class_of[int(obj)]], map.class_names[detected])] += 1
    stats.observations, stats.observations_near = np.array(counts), np.array(near)
    stats.isolated_observations = float(np.mean(isolated)) if isolated else 0.0
    stats.offsets = np.array(offsets)
    return stats


def rows(stats: SceneStats, frames: int) -> list[tuple[str, str, str]]:
    """(statistic key, label, measured) in the order of REAL_SCENES.md."""
    degree_counts = np.bincount(stats.degrees)
    percentiles = np.percentile(stats.offsets, [50, 75, 90, 95]) if len(stats.offsets) else np.zeros(4)
    per_frame = stats.observations
    pairs = ", ".join(f"{a}->{b} {n}" for (a, b), n in stats.confusions.most_common(6))
    return [
        ("objects", "landmarks", f"{stats.objects}"),
        ("classes", "classes", f"{stats.classes}"),
        ("extent_m", "extent (m)", " x ".join(f"{v:.1f}" for v in stats.extent)),
        ("degree_histogram", "degree histogram at 0.8 m (0, 1, 2, ...)", ", ".join(map(str, degree_counts[:12]))
         + (", ..." if len(degree_counts) > 12 else "")),
        ("isolated_objects", "landmarks without a neighbour", f"{np.mean(stats.degrees == 0):.0%}"),
        ("degree_median_max", "degree median / max", f"{np.median(stats.degrees):.0f} / {stats.degrees.max()}"),
        ("observations_per_frame", f"observations per frame (gt, {frames} frames)",
         f"{per_frame.min()} to {per_frame.max()}, median {np.median(per_frame):.0f}"),
        ("observations_near", f"... of them within {NEAR_M} m", f"median {np.median(stats.observations_near):.0f}"),
        ("isolated_observations", "observations isolated in the query graph", f"{stats.isolated_observations:.0%}"),
        ("offset_percentiles", "centre offset 50 / 75 / 90 / 95th pct (m)",
         " / ".join(f"{v:.2f}" for v in percentiles)),
        ("offsets_far", f"centre offsets > {FAR_OFFSET_M} m", f"{np.mean(stats.offsets > FAR_OFFSET_M):.0%}"),
        ("detections_per_frame", f"detections per frame ({stats.detector})", f"{stats.detections / frames:.1f}"),
        ("miss_rate", "mapped objects in view missed", f"{stats.miss_rate:.0%}"),
        ("false_positive_share", "detections hitting no mapped object", f"{stats.false_positive_share:.0%}"),
        ("duplicates_per_frame", "second detections of a hit object", f"{stats.duplicates / frames:.1f} per frame"),
        ("frames_three_hit", "frames hitting 3+ distinct mapped objects", f"{stats.frames_three_hit / frames:.0%}"),
        ("confusion_share", "hits with another class",
         f"{stats.confusion_share:.0%}" + (f" ({pairs})" if pairs else "")),
    ]


def markdown_table(scene: str, detector: str | None = None, frames: int | None = None,
                   data_root: Path | None = None) -> str:
    """The statistics of `scene` beside the real scan's, as a Markdown table (the detector's fault rows only
    when a detector other than ground truth ran)."""
    sequence = open_scene(scene, data_root)
    stats = measure(sequence, detector, frames)
    real = REAL[sequence.kind]
    title = "ScanNet apartment" if sequence.kind == "scannet" else "TUM fr2/desk map"
    lines = [f"| {scene}: statistic | measured | real {title} (REAL_SCENES.md) |", "|---|---|---|"]
    for key, label, value in rows(stats, len(stats.observations)):
        if key not in DETECTOR_FAULTS or stats.detector != "ground-truth":
            lines.append(f"| {label} | {value} | {real[key] or '-'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*",
                        help="demo_apartment, demo_desk, demo, demo_tum, or any sequence name / folder")
    parser.add_argument("--detector", help="detector whose faults are measured [default: the scene's]")
    parser.add_argument("--frames", type=int, help="frames spread over the sequence [default: all]")
    parser.add_argument("--data-root", type=Path)
    parser.add_argument("--readme", type=Path, help="write each table into this file's region "
                        "`<!-- figures:scene_stats_SCENE -->` instead of printing it")
    parser.add_argument("--results", type=Path, action="append", default=[],
                        help="a run's results.json: where it loses its frames, beside the real desk's (repeatable)")
    args = parser.parse_args(argv)
    if not args.scenes and not args.results:
        parser.error("name a scene, or a run's results.json with --results")
    with user_errors("scene_stats"):
        for path in args.results:
            print(f"{path}:\n{failure_profile.table(failure_profile.measure(path, args.data_root))}")
    if not args.scenes:
        return 0
    tables = {f"scene_stats_{scene}": markdown_table(scene, args.detector, args.frames, args.data_root)
              for scene in args.scenes}
    if args.readme is None:
        print("\n".join(tables.values()), end="")
    else:
        args.readme.write_text(update_readme(args.readme.read_text(), tables))
        print(f"{', '.join(args.scenes)}: statistics regenerated in {args.readme}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
