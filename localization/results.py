"""Results of a run on disk: results.json (summary + every frame), poses.tum, config.json.

Each file is written to a temporary name and moved into place, so a file that exists is whole.
JSON holds no NaN: a value that does not exist (no pose, nothing to average) is null.
poses.tum holds the top-1 pose of each localized frame as `timestamp tx ty tz qx qy qz qw`
(camera-to-world, the TUM format evo reads); frames without a pose are left out.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from clipclique.config import METHOD_TITLES
from clipclique.errors import ClipcliqueError
from clipclique.geometry import pose_errors
from clipclique.pipeline import STAGES
from clipclique.types import Pose
from localization.run import QUERY_STAGES, FrameOutcome, Run, RunSettings, execute, prepare

RESULTS_FORMAT = "clipclique-loc results"
RESULTS_VERSION = 1
ALL_STAGES = QUERY_STAGES + STAGES


def write_results(run: Run, out_dir: Path) -> dict[str, Any]:
    """Write results.json, poses.tum and config.json into `out_dir`; the results document."""
    out_dir.mkdir(parents=True, exist_ok=True)
    document = results_document(run)
    atomic_write(out_dir / "results.json", json.dumps(document, indent=1, allow_nan=False))
    atomic_write(out_dir / "poses.tum", tum_trajectory(run.frames))
    atomic_write(out_dir / "config.json", json.dumps(run.config.to_dict(), indent=1, allow_nan=False))
    return document


def atomic_write(path: Path, text: str) -> None:
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(handle, "w") as file:
            file.write(text)
        os.chmod(temporary, 0o644)  # mkstemp makes it private; results are ordinary output files
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


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
    }


def results_document(run: Run) -> dict[str, Any]:
    summary = dict(run.summary())
    summary["stage_ms_median"] = stage_medians(run.frames)
    return json_safe({
        "format": RESULTS_FORMAT,
        "version": RESULTS_VERSION,
        "run": run_description(run),
        "summary": summary,
        "frames": [frame_record(outcome) for outcome in run.frames],
    })


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
        "failure": result.failure,
        "notes": result.notes,
        "hypotheses": hypotheses,
        "evaluation": {
            "translation_error_m": evaluation.translation_error,
            "rotation_error_deg": None if evaluation.rotation_error is None else math.degrees(evaluation.rotation_error),
            "success": {str(k): v for k, v in evaluation.success.items()} if evaluation.has_ground_truth else None,
            "precision": evaluation.precision,
            "recall": evaluation.recall,
            "observations_in_map": evaluation.num_in_map,
        },
        "timings_ms": {stage: 1e3 * outcome.timings.get(stage, 0.0) for stage in ALL_STAGES},
    }


def tum_trajectory(frames: list[FrameOutcome]) -> str:
    lines = ["# timestamp tx ty tz qx qy qz qw (top-1 camera-to-world pose; frames without a pose omitted)"]
    for outcome in frames:
        if outcome.result.hypotheses:
            lines.append(tum_line(outcome.timestamp, outcome.result.hypotheses[0].pose))
    return "\n".join(lines) + "\n"


def tum_line(timestamp: float, pose: Pose) -> str:
    quaternion = Rotation.from_matrix(pose.rotation).as_quat()  # x, y, z, w
    return " ".join(f"{v:.6f}" for v in (timestamp, *pose.translation, *quaternion))


def read_results(path: Path) -> dict[str, Any]:
    """A results.json, checked to be one."""
    try:
        document = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise ClipcliqueError(f"{path}: cannot read results ({error})") from None
    if document.get("format") != RESULTS_FORMAT or document.get("version") != RESULTS_VERSION:
        raise ClipcliqueError(f"{path}: not a version {RESULTS_VERSION} {RESULTS_FORMAT} file")
    return document


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


def run_and_save(settings: RunSettings, progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Prepare, localize every selected frame, write results (and the .rrd); the results document."""
    run = prepare(settings)
    out_dir = writable_folder(settings.out_dir())
    if settings.record:
        from clipclique.viz import LocalizationRecorder

        with LocalizationRecorder(out_dir / "recording.rrd", run.map, recording_description(run),
                                  d_adj=run.config.graph.d_adj) as recorder:
            execute(run, recorder, progress)
    else:
        execute(run, None, progress)
    return write_results(run, out_dir)


def writable_folder(out_dir: Path) -> Path:
    """`out_dir`, created; a folder that cannot be written is a user error before the run, not a
    traceback after it."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ClipcliqueError(f"--out {out_dir}: cannot create the folder ({error.strerror})") from None
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise ClipcliqueError(f"--out {out_dir}: the folder is not writable")
    return out_dir


def recording_description(run: Run) -> str:
    """The recording's text document: what ran, flagged where simulated, and the full config."""
    description = run_description(run)
    parts = [f"# {description['method_title']} on {description['sequence']}",
             f"- map: `{description['map']}` (text embeddings: {description['map_encoder']})"]
    for role in ("detector", "encoder"):
        part = description[role]
        parts.append(f"- {role}: none" if part is None else
                     f"- {role}: {part['name']}{' — **simulated**' if part['simulated'] else ''}")
    parts += [f"- note: {note}" for note in run.notes]
    parts.append(f"\n```json\n{json.dumps(run.config.to_dict(), indent=1)}\n```")
    return "\n".join(parts)
