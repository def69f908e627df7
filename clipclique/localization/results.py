"""Results of a run on disk: results.json (summary + every frame), frames.csv (a row per frame), poses.tum,
config.json; their writers and the reader. The run that makes them is clipclique.localization.run.

The files (and recording.rrd) are staged as `*.partial` and moved into place together once the
run succeeded (clipclique.io.outputs), so a file that exists is whole and belongs to one run.
JSON holds no NaN: a value that does not exist (no pose, nothing to average) is null.
poses.tum holds the top-1 pose of each localized frame as `timestamp tx ty tz qx qy qz qw`
(camera-to-world, the TUM format evo reads); frames without a pose are left out. groundtruth.tum
beside it holds the ground-truth pose of every frame that has one, on the same timestamps, so
`evo_ape tum groundtruth.tum poses.tum` scores any run.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from clipclique.config import METHOD_TITLES, LocalizationConfig, flat, make_config
from clipclique.datasets.tum import tum_line
from clipclique.errors import ClipcliqueError
from clipclique.io.safeio import read_json
from clipclique.localization.runs import FrameOutcome, Run
from clipclique.metrics import SUCCESS_THRESHOLDS_M
from clipclique.outcomes import ALL_STAGES
from clipclique.pose.distance import pose_errors

RESULTS_FORMAT = "clipclique-loc results"
RESULTS_VERSION = 1
OUTPUT_FILES = ("results.json", "frames.csv", "poses.tum", "groundtruth.tum", "config.json")
RECORDING = "recording.rrd"
# --detector yolo also writes what it detected (COCO results, RLE masks, and their image list):
# `--detector file:<run>/detections.json` reruns it without GPU or weights.
DETECTIONS_FILE, IMAGES_FILE = "detections.json", "images.json"


def write_results(run: Run, partials: dict[str, Path], earlier_recording: str | None = None) -> dict[str, Any]:
    """Write results.json, poses.tum, groundtruth.tum and config.json to their staged paths
    (`OUTPUT_FILES` -> path); the results document. Every text is made before any file is written.
    `earlier_recording`: the results digest of a recording this run leaves beside its results ("" unknown)."""
    document = results_document(run, earlier_recording)
    texts = {
        "results.json": json.dumps(document, indent=1, allow_nan=False),
        "frames.csv": frames_csv(document["frames"]),
        "poses.tum": tum_trajectory(run.frames),
        "groundtruth.tum": tum_ground_truth(run.frames),
        "config.json": json.dumps(run.config.to_dict(), indent=1, allow_nan=False),
    }
    for name, text in texts.items():
        partials[name].write_text(text, encoding="utf-8")
    return document


def run_description(run: Run) -> dict[str, Any]:
    """What ran: method, inputs, and which parts are simulated."""
    settings = run.settings
    return {
        "sequence": run.sequence.name,
        "method": settings.method,
        "method_title": METHOD_TITLES[settings.method],
        "map": str(settings.resolved_map_path()),
        "map_encoder": run.map.encoder,
        "detector": {"name": run.detector.name, "simulated": run.detector.simulated},
        "encoder": None if run.encoder is None else {"name": run.encoder.name, "simulated": run.encoder.simulated},
        "notes": run.notes,
        "stride": settings.stride,
        "max_frames": settings.max_frames,
        "sequence_frames": len(run.sequence),
        "name": settings.run_name(),
        "changed": changed_settings(run.config, make_config(settings.method)),
        **({} if run.odometry is None else {"window": {
            "size": settings.window, "step": settings.window_step, "span_s": settings.window_span,
            "odometry": {"name": run.odometry.name, "simulated": run.odometry.simulated,
                         "drift_percent": settings.odometry_drift if run.odometry.simulated else None}}}),
    }


def changed_settings(config: LocalizationConfig, preset: LocalizationConfig) -> dict[str, Any]:
    """Dotted keys whose value differs from the method's preset (overrides, a config file, alpha forced to 0)."""
    defaults = flat(preset)
    return {key: value for key, value in flat(config).items() if value != defaults[key]}


def results_document(run: Run, earlier_recording: str | None = None) -> dict[str, Any]:
    """The results of `run`. Its recording (`run.recording`): the one it wrote, or an earlier run's it left in
    place (`--no-rrd`, `earlier_recording` its results digest), told apart by the results each shows; one
    showing other results gets a note, every time."""
    summary = dict(run.summary())
    if run.odometry is not None:
        summary["window_frames_without_odometry"] = sum(f.window.without_odometry for f in run.frames)
    summary["stage_ms_median"] = stage_medians(run.frames)
    frames = json_safe([frame_record(outcome) for outcome in run.frames])
    digest = results_digest(frames)
    shown = digest if run.settings.record else earlier_recording
    if shown is not None and shown != digest:
        recording = run.settings.out_dir(run.sequence.name) / RECORDING
        run.notes.append(f"{recording} beside these results is an earlier run's and does not show them (--no-rrd "
                         "leaves it as it is; run without --no-rrd to replace it)")
    description = run_description(run) | {
        "results_digest": digest,
        "recording": None if shown is None else {"file": RECORDING, "results_digest": shown,
                                                 "matches": shown == digest},
    }
    return json_safe({
        "format": RESULTS_FORMAT,
        "version": RESULTS_VERSION,
        "run": description,
        "summary": summary,
        "frames": frames,
    })


def results_digest(frames: list[dict[str, Any]]) -> str:
    """What a recording shows of a run, hashed: every frame's record without its timings (deterministic runs
    of the same settings give the same digest, so an earlier recording is known to match or not)."""
    decided = [{key: value for key, value in frame.items() if key != "timings_ms"} for frame in frames]
    return hashlib.sha256(json.dumps(decided, sort_keys=True).encode()).hexdigest()[:16]


def earlier_recording(out_dir: Path) -> str | None:
    """The results digest of the recording already in `out_dir` (as its results.json records it), "" when that
    cannot be told (no readable results.json beside it), None when there is no recording."""
    if not (out_dir / RECORDING).is_file():
        return None
    try:
        recording = read_results(out_dir / "results.json")["run"].get("recording") or {}
    except ClipcliqueError:
        return ""
    return str(recording.get("results_digest") or "")


def stage_medians(frames: list[FrameOutcome]) -> dict[str, float]:
    return {stage: 1e3 * float(np.median([f.timings.get(stage, 0.0) for f in frames])) for stage in ALL_STAGES}


def frame_record(outcome: FrameOutcome) -> dict[str, Any]:
    result, evaluation = outcome.result, outcome.evaluation
    hypotheses = []
    for rank, hypothesis in enumerate(result.hypotheses, start=1):
        te, re = pose_errors(hypothesis.pose, outcome.gt_pose) if outcome.gt_pose is not None else (None, None)
        hypotheses.append({
            "rank": rank,
            "score": hypothesis.score,
            "conditioning": hypothesis.conditioning,
            "verification": hypothesis.verification,
            "confidence": hypothesis.confidence,
            "pose": hypothesis.pose.matrix().tolist(),
            "translation_error_m": te,
            "rotation_error_deg": None if re is None else math.degrees(re),
            "correspondences": hypothesis.correspondences.tolist(),
        })
    return {
        "index": outcome.frame_index,
        "timestamp": outcome.timestamp,
        "name": outcome.name,
        "gt_pose": None if outcome.gt_pose is None else outcome.gt_pose.matrix().tolist(),
        "detections": outcome.num_detections,
        "observations": evaluation.num_observations,
        "dropped": outcome.dropped,
        "candidates": len(result.candidates),
        "num_cliques": result.num_cliques,
        "cap_hit": result.cap_hit,
        "failure": None if result.failure is None else result.failure.message,
        "failure_kind": None if result.failure is None else result.failure.kind.value,
        "notes": result.notes,
        "hypotheses": hypotheses,
        "evaluation": {
            "translation_error_m": evaluation.translation_error,
            "rotation_error_deg": None if evaluation.rotation_error is None
            else math.degrees(evaluation.rotation_error),
            "success": {str(k): v for k, v in evaluation.success.items()} if evaluation.has_ground_truth else None,
            "precision": evaluation.precision,
            "recall": evaluation.recall,
            "observations_in_map": evaluation.num_in_map,
        },
        "timings_ms": {stage: 1e3 * outcome.timings.get(stage, 0.0) for stage in ALL_STAGES},
        **({} if outcome.window is None else {"window": {
            "frames": outcome.window.frames, "without_odometry": outcome.window.without_odometry,
            "observations_with_box": int(outcome.window.observations.has_box.sum())
            if outcome.window.observations.has_box is not None else evaluation.num_observations}}),
    }


FRAME_COLUMNS = ("index", "timestamp", "name", "detections", "observations", "candidates", "localized",
                 "failure_kind", "failure", "translation_error_m", "rotation_error_deg",
                 *(f"within_{t:g}m" for t in SUCCESS_THRESHOLDS_M), "success_top1", "success_top3", "success_top5",
                 "precision", "recall", "confidence", "query_ms", "frame_ms")


def frames_csv(frames: list[dict[str, Any]]) -> str:
    """frames.csv: one row per frame of results.json's `frames` (FRAME_COLUMNS), for a spreadsheet or pandas.
    Empty cells: no value (no pose, no ground truth); booleans 0/1; within_*: the top-1 error below that many
    metres (empty without ground truth)."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(FRAME_COLUMNS)
    for frame in frames:
        evaluation, success = frame["evaluation"], frame["evaluation"]["success"]
        error = evaluation["translation_error_m"]
        within = [None if success is None else error is not None and error < t for t in SUCCESS_THRESHOLDS_M]
        top = frame["hypotheses"][0] if frame["hypotheses"] else {}
        timings = frame["timings_ms"]
        row = [frame["index"], frame["timestamp"], frame["name"], frame["detections"], frame["observations"],
               frame["candidates"], frame["failure"] is None, frame["failure_kind"], frame["failure"], error,
               evaluation["rotation_error_deg"], *within, *(None if success is None else success[k] for k in "135"),
               evaluation["precision"], evaluation["recall"], top.get("confidence"),
               sum(timings[stage] for stage in ("matching", "inliers", "pose")), sum(timings.values())]
        writer.writerow(["" if v is None else int(v) if isinstance(v, bool) else v for v in row])
    return text.getvalue()


def tum_trajectory(frames: list[FrameOutcome]) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw (top-1 camera-to-world pose; frames without a pose omitted)"]
    for outcome in frames:
        if outcome.result.hypotheses:
            lines.append(tum_line(outcome.timestamp, outcome.result.hypotheses[0].pose))
    return "\n".join(lines) + "\n"


def tum_ground_truth(frames: list[FrameOutcome]) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw (ground-truth camera-to-world pose of each frame that has one)"]
    lines += [tum_line(f.timestamp, f.gt_pose) for f in frames if f.gt_pose is not None]
    return "\n".join(lines) + "\n"


def results_files(path: Path) -> list[Path]:
    """The results.json files `path` names: itself, its folder's, or, for a folder of run folders (a sequence's
    outputs/loc/<sequence>), each run's in name order; a folder with none is an error naming it."""
    path = Path(path)
    if not path.is_dir():
        return [path]
    if (path / "results.json").exists():
        return [path / "results.json"]
    runs = sorted(run / "results.json" for run in path.iterdir() if (run / "results.json").is_file())
    if not runs:
        raise ClipcliqueError(f"{path}: holds no results.json, nor run folders that do")
    return runs


def read_results(path: Path) -> dict[str, Any]:
    """A results.json, checked to hold everything the tables read."""
    document = read_json(Path(path), "results file")
    if (not isinstance(document, dict) or document.get("format") != RESULTS_FORMAT
        or document.get("version") != RESULTS_VERSION):
        raise ClipcliqueError(f"{path}: not a version {RESULTS_VERSION} {RESULTS_FORMAT} file")
    problem = schema_problem(document, RESULTS_SCHEMA)
    if problem:
        raise ClipcliqueError(f"{path}: malformed results: {problem}")
    return document


_NUMBER = (int, float, type(None))
_NAMED = {"name": str, "simulated": bool}
RESULTS_SCHEMA: dict[str, Any] = {
    "run": {"sequence": str, "method_title": str, "detector": _NAMED, "encoder": (_NAMED, type(None)), "notes": [str]},
    "summary": {
        **{key: _NUMBER for key in ("frames", "precision", "recall", "te_median_m", "re_median_deg", "success@1",
                                    "success@3", "success@5", "time_ms_median", "te_mean_m", "te_p90_m", "re_mean_deg",
                                    "localized")},
        "success_within_m": {str: _NUMBER},  # any thresholds: a run from before 0.05, 0.1 and 5 m still reads
        "stage_ms_median": {stage: _NUMBER for stage in ALL_STAGES},
    },
}


def schema_problem(value: Any, schema: Any, where: str = "") -> str | None:
    """Where `value` departs from `schema` (a dict of keys, `{str: part}` for any keys, a one-item list, a type or
    a tuple of choices), or None."""
    if isinstance(schema, tuple) and any(isinstance(s, dict) for s in schema):
        problems = [schema_problem(value, s, where) for s in schema]
        return None if None in problems else problems[0]
    if isinstance(schema, dict) and list(schema) == [str]:
        if not isinstance(value, dict):
            return f"{where.removesuffix('.')} is not an object"
        return next((p for key, item in value.items() if (p := schema_problem(item, schema[str], f"{where}{key}."))),
                    None)
    if isinstance(schema, dict):
        if not isinstance(value, dict):
            return f"{where or 'the document'} is not an object"
        for key, part in schema.items():
            if key not in value:
                return f"{where}{key} missing"
            if problem := schema_problem(value[key], part, f"{where}{key}."):
                return problem
        return None
    if isinstance(schema, list):
        if not isinstance(value, list):
            return f"{where.removesuffix('.')} is not a list"
        return next((p for item in value if (p := schema_problem(item, schema[0], where))), None)
    if not isinstance(value, schema):
        return f"{where.removesuffix('.')} has the wrong type ({type(value).__name__})"
    return None


def json_safe(value: Any) -> Any:
    """The same tree with NaN/inf floats as None and numpy scalars as Python ones."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
