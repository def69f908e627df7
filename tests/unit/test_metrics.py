import math

import numpy as np
import pytest

from clipclique.config import make_config
from clipclique.metrics import FrameEvaluation, evaluate_frame, summarize
from clipclique.outcomes import Failure, FailureKind
from clipclique.pipeline import LocalizationResult
from clipclique.types import Ellipsoids, Hypothesis, Map, Observations, Pose


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


MAP = Map(Ellipsoids.empty(), np.zeros(4, int), ["thing"], [""] * 4, instance_ids=np.array([10, 11, 12, 13]))
# observations see objects 10, 11, 12 and 99 (not in the map) plus a false detection (-1)
OBSERVATIONS = Observations(
    Ellipsoids.empty(), np.zeros(5, int), None, instance_ids=np.array([10, 11, 12, 99, -1]),
    detection_index=np.arange(5)
)
TRUTH = Pose(np.eye(3), np.zeros(3))


def result_with(poses: list[Pose], top1_pairs: np.ndarray) -> LocalizationResult:
    hypotheses = [Hypothesis(p, top1_pairs if i == 0 else top1_pairs[:0], 1.0) for i, p in enumerate(poses)]
    timings = {"descriptors": 5.0, "similarity": 5.0, "matching": 0.001, "inliers": 0.002, "pose": 0.003}
    return LocalizationResult(hypotheses=hypotheses, candidates=np.zeros((0, 2), int), candidate_scores=np.zeros(0),
                              similarity=np.zeros((5, 4)), num_cliques=1, cap_hit=None, failure=None, timings=timings)


def test_evaluate_frame_scores_poses_and_correspondences():
    poses = [Pose(rotation_z(0.1), np.array([3.0, 0, 0])), Pose(np.eye(3), np.array([0, 0.5, 0])), TRUTH]
    pairs = np.array([[0, 0], [1, 2], [2, 2], [4, 3]])  # correct: 0->10, 2->12; wrong: 1->12, false detection
    evaluation = evaluate_frame(result_with(poses, pairs), OBSERVATIONS, MAP, TRUTH, make_config(), frame_index=7)
    assert evaluation.frame_index == 7
    assert evaluation.translation_error == pytest.approx(3.0)
    assert evaluation.rotation_error == pytest.approx(0.1)
    assert evaluation.success == {1: False, 3: True, 5: True}
    assert evaluation.precision == pytest.approx(2 / 4)
    assert evaluation.recall == pytest.approx(2 / 3) and evaluation.num_in_map == 3
    assert evaluation.time_s == pytest.approx(0.006)
    assert evaluation.num_observations == 5


def test_no_pose_and_no_ground_truth():
    failed = result_with([], np.zeros((0, 2), int))
    failed.failure = Failure(kind=FailureKind.FEW_OBSERVATIONS, count=2)
    evaluation = evaluate_frame(failed, OBSERVATIONS, MAP, TRUTH, make_config(), 0)
    assert evaluation.translation_error is None and evaluation.precision is None
    assert evaluation.success == {1: False, 3: False, 5: False} and evaluation.recall == 0.0
    assert evaluation.failure is failed.failure and evaluation.failure.message == "fewer than 3 observations (2)"
    unknown = evaluate_frame(result_with([TRUTH], np.array([[0, 0]])), OBSERVATIONS, MAP, None, make_config(), 0)
    assert unknown.translation_error is None and unknown.precision == 1.0


def evaluation(te, re, success1, precision, recall, in_map=3, time_s=0.01, failure=None):
    return FrameEvaluation(frame_index=0, translation_error=te, rotation_error=re,
                           success={1: success1, 3: success1, 5: True}, precision=precision, recall=recall,
                           num_observations=5, failure=failure, time_s=time_s, num_in_map=in_map)


def test_summarize_aggregates_as_documented():
    summary = summarize(
        [
            evaluation(0.2, 0.1, True, 1.0, 1.0),
            evaluation(4.0, 0.3, False, 0.5, 0.5, time_s=0.03),
            evaluation(0.4, 0.2, True, 0.9, 0.0, in_map=0),  # recall undefined: not averaged
            evaluation(None, None, False, None, 0.0, failure=Failure(kind=FailureKind.NO_CLIQUE, count=3)),
        ]
    )
    assert summary["frames"] == 4
    assert summary["success@1"] == 0.5 and summary["success@5"] == 1.0
    assert summary["localized"] == 0.75
    assert summary["precision"] == pytest.approx(0.8)
    assert summary["recall"] == pytest.approx(0.5)
    assert summary["te_median_m"] == pytest.approx(0.4)
    assert summary["re_median_deg"] == pytest.approx(np.degrees(0.2))
    assert summary["time_ms_mean"] == pytest.approx(15.0) and summary["time_ms_median"] == pytest.approx(10.0)
    assert math.isnan(summarize([])["precision"])
    assert isinstance(summary["frames"], int)
    # top-1 errors 0.2, 4.0, 0.4 and no pose: within 0.05 / 0.1 / 0.25 / 0.5 / 1 / 2 / 5 m of the 4 frames
    assert summary["success_within_m"] == {"0.05": 0.0, "0.1": 0.0, "0.25": 0.25, "0.5": 0.5, "1": 0.5, "2": 0.5,
                                           "5": 0.75}
    assert (summary["te_mean_m"] == pytest.approx(4.6 / 3)
            and summary["te_p90_m"] == pytest.approx(np.percentile([0.2, 4, 0.4], 90)))
    assert (summary["re_mean_deg"] == pytest.approx(np.degrees(0.2))
            and summary["re_p75_deg"] == pytest.approx(np.degrees(0.25)))


def test_frames_without_ground_truth_do_not_count_in_success():
    scored = evaluate_frame(result_with([TRUTH], np.array([[0, 0]])), OBSERVATIONS, MAP, TRUTH, make_config(), 0)
    unscored = evaluate_frame(result_with([TRUTH], np.array([[0, 0]])), OBSERVATIONS, MAP, None, make_config(), 1)
    assert scored.has_ground_truth and not unscored.has_ground_truth
    summary = summarize([scored, unscored])  # a perfect pose and one that cannot be scored: 100 %, not 50 %
    assert summary["success@1"] == 1.0 and summary["frames"] == 2 and summary["localized"] == 1.0
    assert math.isnan(summarize([unscored])["success@1"])


def test_a_map_without_ground_truth_ids_has_no_precision():
    import dataclasses

    imported = dataclasses.replace(MAP, instance_ids=np.full(len(MAP.instance_ids), -1))
    pairs = np.array([[0, 0], [1, 2], [2, 2]])
    evaluation = evaluate_frame(result_with([TRUTH], pairs), OBSERVATIONS, imported, TRUTH, make_config(), 0)
    assert evaluation.precision is None and evaluation.num_in_map == 0 and evaluation.success[1]
    assert (evaluate_frame(result_with([TRUTH], pairs), OBSERVATIONS, MAP, TRUTH, make_config(), 0).precision
            == pytest.approx(2 / 3))
