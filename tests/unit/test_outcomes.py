"""Outcomes as types: each failure's message (what results.json has always said) derived from its kind."""

from __future__ import annotations

import json

from clipclique.outcomes import ALL_STAGES, PIPELINE_STAGES, QUERY_STAGES, CapHit, Failure, FailureKind, Stage

MESSAGES = {  # the texts results.json held before failures were typed
    Failure(kind=FailureKind.FEW_OBSERVATIONS, count=2): "fewer than 3 observations (2)",
    Failure(kind=FailureKind.FEW_MATCHED, count=0): "fewer than 3 observations with a candidate landmark (0)",
    Failure(kind=FailureKind.NO_CLIQUE, count=4): "no clique of 4 or more compatible correspondences",
    Failure(kind=FailureKind.NO_MINIMAL_SET): "no minimal set of 3 distinct, non-collinear correspondences",
    Failure(kind=FailureKind.DEGENERATE):
        "no correspondence set determines a pose (each is collinear or poorly conditioned)",
    Failure(kind=FailureKind.NOT_CONFIDENT, min_confidence=0.9, best_confidence=0.4567):
        "no pose with confidence >= 0.9 (best 0.46)",
    Failure(kind=FailureKind.NO_POSE): "no pose",
}


def test_every_kind_has_its_message_and_a_tally_reason_without_the_frame_count():
    assert {failure.kind for failure in MESSAGES} == set(FailureKind)
    for failure, message in MESSAGES.items():
        assert failure.message == str(failure) == message
    reasons = {failure.kind: failure.reason for failure in MESSAGES}
    assert reasons[FailureKind.FEW_OBSERVATIONS] == "fewer than 3 observations"
    assert reasons[FailureKind.FEW_MATCHED] == "fewer than 3 observations with a candidate landmark"
    assert reasons[FailureKind.NO_CLIQUE] == "no clique of 4 or more compatible correspondences"


def test_stages_and_caps_serialize_as_their_names():
    assert [str(stage) for stage in ALL_STAGES] == ["detector", "observations", "encoder", "descriptors", "similarity",
                                                   "matching", "inliers", "pose", "verification"]
    assert set(ALL_STAGES) == set(Stage) and ALL_STAGES == QUERY_STAGES + PIPELINE_STAGES
    assert json.loads(json.dumps({Stage.POSE: 1.0, "cap": CapHit.MAX_PAIRS})) == {"pose": 1.0, "cap": "max_pairs"}
    assert {"pose": 2.0}[Stage.POSE] == 2.0  # timings keyed by Stage read by plain names
