"""Where a run loses its frames: issue 37's table of a results.json, beside the real desk's (docs/REAL_SCENES.md).

    .venv/bin/python tools/scene_stats.py --results outputs/loc/demo_sparse/clipclique/results.json

Each frame with ground truth falls in one row, in this order: top-1 within 0.5 m; the right pose (within
0.5 m) among ranks 2-5 below a wrong top-1; top-1 0.5-2 m off; more than 2 m off; no pose. Per row: frames,
and the medians of detections, of distinct mapped objects hit and of those hit by a detection of their own
class. Hits are measured as scene_stats measures them (a detection hits the mapped object covering half its
mask), with the run's detector rebuilt (simulated detectors are seeded per frame: the run's detections).
Then the runs of failures (frames off by 0.5 m or more, or without a pose) in the run's frame order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from clipclique.backends import make_detector
from clipclique.errors import ClipcliqueError
from clipclique.io.mapfile import load_map
from clipclique.localization.results import read_results, schema_problem
from clipclique.mapping.build import build_map
from clipclique.resolve import open_scene
from clipclique.types import Detections, Frame

NEAR_M, FAR_M = 0.5, 2.0
LONG_RUN_S = 1.0  # "runs of 30 frames or longer" at 30 Hz
ROWS = ("within 0.5 m", "0.5-2 m off (right place, imprecise pose)", "more than 2 m off",
        "right pose in the top 5, ranked below a wrong one", "no pose")
# The real desk's held-back detections (2,257 frames, single frame, default method; issue 37): per row
# (frames, median detections, distinct mapped objects hit, of them with the right class).
REAL_ROWS = {ROWS[0]: (1771, 12, 10, 6), ROWS[1]: (216, 7, 4, 2), ROWS[2]: (199, 5, 3, 1), ROWS[3]: (65, 7, 5, 3),
             ROWS[4]: (6, None, None, None)}
_NUMBER = (int, float, type(None))
FRAMES_SCHEMA = [{"index": int, "timestamp": (int, float), "hypotheses": [{"translation_error_m": _NUMBER}],
                  "evaluation": {"success": (dict, type(None))}}]  # what measure reads of results.json's frames
REAL_RUNS = {"runs": "104", "median run": "1 frame", "frames in runs of 1 s or longer": "245",
             "longest run": "164 frames (5.5 s)"}


@dataclass
class FrameHits:
    """One frame of a run: which row it falls in, its detections and what they hit."""

    row: str
    detections: int
    objects_hit: int
    right_class: int
    timestamp: float


def hit_objects(frame: Frame, detections: Detections, mapped: np.ndarray) -> np.ndarray:
    """(K,) the mapped object id covering at least half of each detection's mask, 0 for none."""
    out = np.zeros(len(detections), int)
    if frame.instances is None:
        return out
    for k, mask in enumerate(detections.masks):
        ids, counts = np.unique(frame.instances[mask], return_counts=True)
        best = int(np.argmax(counts)) if len(ids) else 0
        if len(ids) and ids[best] in mapped and counts[best] >= 0.5 * mask.sum():
            out[k] = ids[best]
    return out


def frame_row(frame: dict[str, Any]) -> str | None:
    """The frame's row of ROWS (None without ground truth)."""
    if frame["evaluation"]["success"] is None:
        return None
    errors = [np.inf if h["translation_error_m"] is None else h["translation_error_m"] for h in frame["hypotheses"]]
    if not errors:
        return ROWS[4]
    if errors[0] < NEAR_M:
        return ROWS[0]
    if any(e < NEAR_M for e in errors[1:5]):
        return ROWS[3]
    return ROWS[1] if errors[0] < FAR_M else ROWS[2]


def measure(path: Path, data_root: Path | None = None) -> list[FrameHits]:
    """Every frame of the results.json at `path` with ground truth, its row and its detector's hits."""
    document = read_results(path)
    if problem := schema_problem(document.get("frames"), FRAMES_SCHEMA, "frames."):
        raise ClipcliqueError(f"{path}: malformed results: {problem}")
    run = document["run"]
    sequence = open_scene(run["sequence"], data_root)
    outside = [r["index"] for r in document["frames"] if not 0 <= r["index"] < len(sequence)]
    if outside:
        raise ClipcliqueError(f"{path}: frame index {outside[0]} is not a frame of {run['sequence']} "
                              f"(0 to {len(sequence) - 1})")
    map_path = Path(run.get("map") or "")
    map = load_map(map_path) if map_path.is_file() else build_map(sequence, encoder=None)[0]
    try:
        detector = make_detector(run["detector"]["name"], sequence.object_classes(), map.class_names)
    except ClipcliqueError as error:
        raise ClipcliqueError(f"{path}: cannot rebuild the run's detector to count its hits ({error})") from None
    class_of = dict(zip(map.instance_ids.tolist(), map.class_ids.tolist()))
    frames = []
    for record in document["frames"]:
        row = frame_row(record)
        if row is None:
            continue
        frame = sequence[record["index"]]
        detections = detector.detect(frame)
        hits = hit_objects(frame, detections, map.instance_ids)
        right = {int(h) for h, c in zip(hits, detections.class_ids) if h and class_of[int(h)] == c}
        frames.append(FrameHits(row, len(detections), len(set(hits[hits > 0].tolist())), len(right),
                                float(record["timestamp"])))
    return frames


def failure_runs(frames: list[FrameHits]) -> list[tuple[int, float]]:
    """Runs of consecutive failed frames (off by NEAR_M or more, or no pose): (frames, seconds) each, a run's
    seconds its frames times the run's median frame interval."""
    times = np.array([f.timestamp for f in frames])
    step = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    runs, length = [], 0
    for frame in [*frames, None]:
        if frame is not None and frame.row != ROWS[0]:
            length += 1
        elif length:
            runs.append((length, length * step))
            length = 0
    return runs


def table(frames: list[FrameHits]) -> str:
    """Markdown: each row measured beside the real desk's, then the failure runs beside the real ones."""
    def median(values: list[int]) -> str:
        return f"{np.median(values):g}" if values else "-"

    def real(value: int | None) -> str:
        return "-" if value is None else f"{value:,}"

    lines = ["| frames | count | median detections | distinct mapped objects hit | of them with the right class |",
             "|---|---|---|---|---|"]
    for row in ROWS:
        chosen = [f for f in frames if f.row == row]
        measured = [f"{len(chosen)}"] + ([median([getattr(f, k) for f in chosen])
                                          for k in ("detections", "objects_hit", "right_class")]
                                         if row != ROWS[4] else ["-"] * 3)
        cells = [f"{m} (real {real(r)})" for m, r in zip(measured, REAL_ROWS[row])]
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    runs = failure_runs(frames)
    lengths = [n for n, _ in runs]
    longest = max(runs, default=(0, 0.0))
    typical = median(lengths)
    measured = {"runs": f"{len(runs)}", "median run": f"{typical} frame{'' if typical == '1' else 's'}",
                "frames in runs of 1 s or longer": f"{sum(n for n, s in runs if s >= LONG_RUN_S - 1e-9)}",
                "longest run": f"{longest[0]} frames ({longest[1]:.1f} s)"}
    lines += ["", "| failure runs (0.5 m or more off, or no pose) | measured | real |", "|---|---|---|"]
    lines += [f"| {key} | {value} | {REAL_RUNS[key]} |" for key, value in measured.items()]
    return "\n".join(lines) + "\n"
