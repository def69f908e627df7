"""The benchmark's perception cache gives back what it was given: a lever that reads the detector's
score (`Observations.scores`) is measured on the scores the detector gave, not on none."""

from __future__ import annotations

import dataclasses

import numpy as np

from clipclique.benchmark import perception
from clipclique.localization.run import Seen
from clipclique.sim.synthetic import synthetic_map, synthetic_query
from clipclique.types import Detections


def seen_with(observations) -> Seen:
    count = len(observations)
    detections = Detections(np.zeros((count, 2, 2), bool), observations.boxes, observations.class_ids,
                            observations.scores, observations.instance_ids)
    return Seen(detections, observations, {}, {})


def test_a_cached_frame_keeps_the_detectors_scores(tmp_path):
    rng = np.random.default_rng(3)
    observations, pose = synthetic_query(synthetic_map(rng), rng)
    scored = dataclasses.replace(observations, scores=rng.uniform(0.25, 0.95, len(observations)))
    path = tmp_path / "000000.npz"
    perception.save(path, 0, 0.0, "frame", pose, seen_with(scored))
    np.testing.assert_array_equal(perception.load(path).observations.scores, scored.scores)
    perception.save(path, 0, 0.0, "frame", pose, seen_with(dataclasses.replace(scored, scores=None)))
    assert perception.load(path).observations.scores is None  # a detector without scores: still none
