"""Scoring one frame's localization against ground truth, and the paper's summary columns.

Aggregation choices: translation/rotation errors are summarized by the median over the frames
that have both a top-1 pose and a ground-truth pose (all of them, not only the successes);
success rates divide by every frame with a ground-truth pose (no estimated pose = failure; a
frame without ground truth cannot be scored, so it counts neither way); precision averages over
frames with a top-1 hypothesis, recall over frames where some observed object is in the map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clipclique.config import LocalizationConfig
from clipclique.outcomes import ALGORITHM_STAGES, Failure, FailureKind, LocalizationResult
from clipclique.pose.distance import pose_errors
from clipclique.types import Map, Observations, Pose

TOP_K = (1, 3, 5)
# The project's success thresholds (metres of top-1 translation error), the one definition every summary,
# table and benchmark reports "success within" by: MSG-Loc's protocol (0.05 to 5 m) with 0.25 m between; the
# paper's Top-k uses config.success_threshold_m (1 m).
SUCCESS_THRESHOLDS_M = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0)
ERROR_PERCENTILES = (75, 90, 95)  # beside the median (te_median_m, re_median_deg), the paper's column


@dataclass(kw_only=True)
class FrameEvaluation:
    frame_index: int
    translation_error: float | None  # metres, top-1 pose vs ground truth; None when no pose
    rotation_error: float | None  # radians
    success: dict[int, bool]  # {1: .., 3: .., 5: ..}: any of the top-k poses has TE < threshold
    precision: float | None  # top-1 correspondences that are correct (by instance id)
    recall: float  # correct top-1 correspondences / observations whose object is in the map
    num_observations: int
    failure: Failure | None
    time_s: float  # matching + inliers + pose (the algorithm), seconds
    num_in_map: int = 0  # observations whose object is in the map (recall's denominator)
    has_ground_truth: bool = True  # False: no ground-truth pose, so success is undefined (left out of success@k)


def evaluate_frame(
    result: LocalizationResult,
    observations: Observations,
    map: Map,
    gt_pose: Pose | None,
    config: LocalizationConfig,
    frame_index: int,
) -> FrameEvaluation:
    """Errors and success of the ranked poses, and correctness of the top-1 correspondences.

    A correspondence is correct when the observation's ground-truth instance id (not -1) equals
    the landmark's. Recall is 0 when no observed object is in the map (`num_in_map` tells).
    A map without ground-truth object ids (an imported SLAM map: every id -1) has no precision
    (None) and no observed object in it, so neither enters the summary's means.
    """
    errors = [pose_errors(h.pose, gt_pose) for h in result.hypotheses] if gt_pose is not None else []
    success = {k: any(te < config.success_threshold_m for te, _ in errors[:k]) for k in TOP_K}
    known = observations.instance_ids >= 0
    num_in_map = int(np.count_nonzero(known & np.isin(observations.instance_ids, map.instance_ids)))
    precision = None
    correct = 0
    if result.hypotheses and (map.instance_ids >= 0).any():
        pairs = result.hypotheses[0].correspondences
        observed = observations.instance_ids[pairs[:, 0]]
        correct = int(np.count_nonzero((observed >= 0) & (observed == map.instance_ids[pairs[:, 1]])))
        precision = correct / len(pairs)
    return FrameEvaluation(
        frame_index=frame_index,
        translation_error=errors[0][0] if errors else None,
        rotation_error=errors[0][1] if errors else None,
        success=success,
        precision=precision,
        recall=correct / num_in_map if num_in_map else 0.0,
        num_observations=len(observations),
        failure=result.failure,
        time_s=sum(result.timings.get(stage, 0.0) for stage in ALGORITHM_STAGES),
        num_in_map=num_in_map,
        has_ground_truth=gt_pose is not None,
    )


def success_within(errors: list[float | None],
                   thresholds: tuple[float, ...] = SUCCESS_THRESHOLDS_M) -> dict[str, float]:
    """Per threshold (keyed `"0.25"`, `"1"`, ...), the fraction of `errors` (one per frame with ground truth; None:
    no pose, a failure) below it; NaN without frames."""
    return {f"{t:g}": _mean([float(e is not None and e < t) for e in errors]) for t in thresholds}


def error_statistics(values: list[float], name: str, unit: str) -> dict[str, float]:
    """The mean and ERROR_PERCENTILES of `values`, keyed `<name>_mean_<unit>`, `<name>_p90_<unit>`, ...; NaN
    without values."""
    statistics = {f"{name}_mean_{unit}": _mean(values)}
    for p in ERROR_PERCENTILES:
        statistics[f"{name}_p{p}_{unit}"] = float(np.percentile(values, p)) if values else math.nan
    return statistics


def summarize(evaluations: list[FrameEvaluation]) -> dict[str, object]:
    """The paper's columns over frames: success@1/3/5 (fractions), precision, recall, median TE (m)
    and RE (deg), time per query (ms), and the frames left without a pose by `min_confidence`; beside them
    top-1 success within each of SUCCESS_THRESHOLDS_M (`success_within_m`) and the mean and percentiles of
    TE and RE. A column with no frame to average over is NaN."""
    te = [e.translation_error for e in evaluations if e.translation_error is not None]
    re = [e.rotation_error for e in evaluations if e.rotation_error is not None]
    summary: dict[str, object] = {"frames": len(evaluations)}
    for k in TOP_K:
        summary[f"success@{k}"] = _mean([float(e.success[k]) for e in evaluations if e.has_ground_truth])
    summary["success_within_m"] = success_within([e.translation_error for e in evaluations if e.has_ground_truth])
    summary["localized"] = _mean([float(e.failure is None) for e in evaluations])
    summary["not_confident"] = int(sum(e.failure is not None and e.failure.kind is FailureKind.NOT_CONFIDENT
                                       for e in evaluations))
    summary["failures"] = failure_counts(evaluations)
    summary["precision"] = _mean([e.precision for e in evaluations if e.precision is not None])
    summary["recall"] = _mean([e.recall for e in evaluations if e.num_in_map > 0])
    summary["te_median_m"] = float(np.median(te)) if te else math.nan
    summary["re_median_deg"] = float(np.degrees(np.median(re))) if re else math.nan
    summary |= error_statistics(te, "te", "m") | error_statistics([math.degrees(r) for r in re], "re", "deg")
    summary["time_ms_mean"] = _mean([1e3 * e.time_s for e in evaluations])
    summary["time_ms_median"] = float(np.median([1e3 * e.time_s for e in evaluations])) if evaluations else math.nan
    return summary


def failure_counts(evaluations: list[FrameEvaluation]) -> dict[str, int]:
    """Frames without a pose by why (FailureKind values), most frequent first."""
    counts: dict[str, int] = {}
    for e in evaluations:
        if e.failure is not None:
            counts[e.failure.kind.value] = counts.get(e.failure.kind.value, 0) + 1
    return dict(sorted(counts.items(), key=lambda item: -item[1]))


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else math.nan
