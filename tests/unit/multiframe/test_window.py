"""Window fusion on hand-made observation sets: what merges, what keeps a box, which frames drop out."""

from __future__ import annotations

import numpy as np
import pytest

from clipclique import pipeline
from clipclique.config import make_config
from clipclique.multiframe.window import WindowConfig, Windower, fuse, fusion, relative_poses, span_step, window_frames
from clipclique.sim.poses import look_at
from clipclique.sim.synthetic import SIMULATED_CAMERA, synthetic_map, synthetic_query
from clipclique.types import Ellipsoids, Observations, Pose
from clipclique.verify import verification

NAMES = ["cup", "bottle", "chair", "book"]
CUP, BOTTLE, CHAIR, BOOK = range(4)


def frame(centers, classes, axes=0.05, instances=None, boxes=True) -> Observations:
    """Axis-aligned observations at `centers` (camera frame), each with a box and detection index."""
    centers = np.asarray(centers, float).reshape(-1, 3)
    count = len(centers)
    axes = np.broadcast_to(np.asarray(axes, float), (count, 3)).copy() if np.ndim(axes) < 2 else np.asarray(axes, float)
    return Observations(
        Ellipsoids(centers, axes, np.repeat(np.eye(3)[None], count, axis=0)),
        np.asarray(classes, np.int64),
        None,
        np.arange(count) + 1 if instances is None else np.asarray(instances, np.int64),
        np.arange(count) + 10,
        np.tile([100.0, 100.0, 150.0, 150.0], (count, 1)) if boxes else None,
        np.full(count, 500, np.int64),
        SIMULATED_CAMERA,
    )


def shift(x: float) -> Pose:
    return Pose(np.eye(3), np.array([x, 0.0, 0.0]))


def test_same_object_merges_and_keeps_the_newest_box_others_have_none():
    older = frame([[0.5, 0.0, 2.0], [-1.0, 0.0, 3.0]], [CUP, CHAIR], instances=[7, 8])
    newest = frame([[0.22, 0.0, 2.0]], [CUP], instances=[7])
    # the older camera sat 0.3 m to the left: its x is the newest's x + 0.3
    fused = fusion([older, newest], [shift(-0.3), Pose.identity()], WindowConfig(size=2), NAMES)
    obs = fused.observations
    assert len(obs) == 2
    np.testing.assert_allclose(obs.ellipsoids.centers[0], [0.21, 0.0, 2.0])  # mean of 0.2 and 0.22
    np.testing.assert_allclose(obs.ellipsoids.centers[1], [-1.3, 0.0, 3.0])
    assert obs.has_box.tolist() == [True, False]
    assert obs.detection_index.tolist() == [10, -1]
    np.testing.assert_array_equal(obs.boxes[1], np.zeros(4))
    assert obs.mask_areas.tolist() == [500, 0]
    assert obs.class_ids.tolist() == [CUP, CHAIR] and obs.instance_ids.tolist() == [7, 8]
    assert [m.tolist() for m in fused.members] == [[[1, 0], [0, 0]], [[0, 1]]]


def test_far_apart_or_other_class_stays_apart():
    older = frame([[0.4, 0.0, 2.0], [0.0, 0.0, 2.5]], [CUP, CHAIR])
    newest = frame([[0.0, 0.0, 2.0], [0.0, 0.0, 2.5]], [CUP, BOOK])  # cup 0.4 m away; chair where the book is
    assert len(fuse([older, newest], [Pose.identity()] * 2, WindowConfig(size=2), NAMES)) == 4


def test_lookalike_classes_merge_only_with_names_and_the_majority_class_wins():
    frames = [frame([[0.0, 0.0, 2.0]], [c]) for c in (CUP, CUP, BOTTLE)]  # newest says bottle
    poses = [Pose.identity()] * 3
    merged = fuse(frames, poses, WindowConfig(size=3), NAMES)
    assert len(merged) == 1 and merged.class_ids.tolist() == [CUP]
    assert len(fuse(frames, poses, WindowConfig(size=3))) == 2  # without names, cup and bottle stay two


def test_two_detections_of_one_frame_never_merge_and_pairs_go_nearest_first():
    older = frame([[0.03, 0.0, 2.0], [0.0, 0.0, 2.0]], [CUP, CUP])
    newest = frame([[0.0, 0.0, 2.0]], [CUP])
    fused = fusion([older, newest], [Pose.identity()] * 2, WindowConfig(size=2), NAMES)
    assert len(fused.observations) == 2
    assert fused.members[0].tolist() == [[1, 0], [0, 1]]  # the exact match, not the 3 cm one


def test_moments_of_identical_members_keep_the_shape_and_of_offset_members_stretch_it():
    axes = [[0.3, 0.2, 0.1]]
    same = fuse([frame([[0, 0, 2]], [CHAIR], axes), frame([[0, 0, 2]], [CHAIR], axes)], [Pose.identity()] * 2,
                WindowConfig(size=2))
    np.testing.assert_allclose(same.ellipsoids.axes[0], axes[0])
    # two partial views of one object: spheres of radius 0.3, 0.25 m apart -> longer along the offset
    halves = fuse([frame([[-0.125, 0, 2]], [CHAIR], 0.3), frame([[0.125, 0, 2]], [CHAIR], 0.3)], [Pose.identity()] * 2,
                  WindowConfig(size=2))
    np.testing.assert_allclose(halves.ellipsoids.centers[0], [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(halves.ellipsoids.axes[0], [np.sqrt(0.09 + 5 * 0.125**2), 0.3, 0.3])
    np.testing.assert_allclose(np.abs(halves.ellipsoids.rotations[0][:, 0]), [1, 0, 0], atol=1e-12)
    assert np.linalg.det(halves.ellipsoids.rotations[0]) == pytest.approx(1.0)


def test_embeddings_are_the_renormalized_mean():
    a, b = frame([[0, 0, 2]], [CUP]), frame([[0, 0, 2]], [CUP])
    a.image_embeddings = np.array([[1.0, 0.0]], np.float32)
    b.image_embeddings = np.array([[0.0, 1.0]], np.float32)
    fused = fuse([a, b], [Pose.identity()] * 2, WindowConfig(size=2))
    np.testing.assert_allclose(fused.image_embeddings, [[np.sqrt(0.5), np.sqrt(0.5)]], rtol=1e-6)


def test_one_frame_is_returned_as_it_is():
    alone = frame([[0, 0, 2], [1, 0, 2]], [CUP, BOOK])
    assert fuse([alone], [Pose.identity()]) is alone


def test_rotated_odometry_moves_observations_into_the_newest_camera():
    truth = [look_at(np.array([x, -2.0, 1.0]), np.array([0.0, 0.0, 0.5])) for x in (-0.5, 0.0)]
    point = np.array([0.1, 0.2, 0.6])
    older, newest = (frame([pose.inverse().apply(point)], [CUP]) for pose in truth)
    to_newest = truth[1].inverse().compose(truth[0])
    fused = fuse([older, newest], [to_newest, Pose.identity()], WindowConfig(size=2))
    assert len(fused) == 1
    np.testing.assert_allclose(fused.ellipsoids.centers[0], truth[1].inverse().apply(point), atol=1e-12)


def test_window_frames():
    assert window_frames(2, WindowConfig(size=5)) == [0, 1, 2]  # the first frames have a shorter window
    assert window_frames(10, WindowConfig(size=3, step=2)) == [6, 8, 10]
    assert window_frames(3, WindowConfig(size=5, step=2)) == [1, 3]
    assert window_frames(7, WindowConfig(size=1, step=4)) == [7]


def test_a_span_is_the_step_that_spreads_the_window_over_it():
    at_30_hz = 1_700_000_000.0 + np.arange(300) / 30.0 + np.random.default_rng(0).uniform(-0.002, 0.002, 300)
    assert span_step(3.0, 10, at_30_hz) == 10  # 9 intervals of 10 frames: 3 s
    assert span_step(6.0, 5, at_30_hz) == 45 and span_step(1.2, 5, at_30_hz) == 9
    assert span_step(0.01, 5, at_30_hz) == 1  # never below every frame
    assert span_step(3.0, 10, at_30_hz[::3]) == 3  # at 10 Hz
    assert span_step(3.0, 1, at_30_hz) == 1 and span_step(3.0, 5, at_30_hz[:1]) == 1  # nothing to spread
    frames = window_frames(299, WindowConfig(size=5, step=span_step(1.2, 5, at_30_hz)))
    assert frames == [263, 272, 281, 290, 299]
    assert 1.19 < at_30_hz[frames[-1]] - at_30_hz[frames[0]] < 1.21


def test_frames_without_odometry_leave_the_window():
    odometry = [shift(0.0), None, shift(1.0), shift(3.0)]
    poses, kept = relative_poses(odometry)
    assert kept.tolist() == [True, False, True, True]
    np.testing.assert_allclose([p.translation[0] for p in poses], [-3.0, -2.0, 0.0])
    poses, kept = relative_poses([shift(0.0), shift(1.0), None])  # the newest has none: it is alone
    assert kept.tolist() == [False, False, True] and len(poses) == 1


def test_verification_and_confidence_read_only_observations_with_a_box():
    rng = np.random.default_rng(3)
    map = synthetic_map(rng, num_landmarks=30)
    query, truth = synthetic_query(map, rng, num_visible=10, num_outliers=0, center_noise=0.01)
    query.has_box = np.arange(len(query)) < 6  # the last four were seen only by older frames
    config = make_config("clipclique")
    result = pipeline.localize(query, pipeline.index_map(map, config), config)
    assert result.hypotheses and np.linalg.norm(result.hypotheses[0].pose.translation - truth.translation) < 0.2
    best = result.hypotheses[0]
    seen = best.correspondences[best.correspondences[:, 0] < 6]
    assert 0 < len(seen) < len(best.correspondences)
    from dataclasses import replace
    expected = verification.verify([replace(best, correspondences=seen)], query.subset(np.arange(6)), map)
    assert best.verification == pytest.approx(expected.score[0])
    full = verification.verify([best], query, map)
    assert best.verification != pytest.approx(full.score[0])


def test_windower_observes_each_frame_once_and_counts_frames_without_odometry():
    sets = {i: frame([[-0.1 * i, 0.0, 2.0]], [CUP], instances=[1]) for i in range(6)}  # a cup at world x = 0
    odometry = [shift(0.1 * i) for i in range(6)]
    odometry[3] = None
    observed = []

    def observe(i):
        observed.append(i)
        return sets[i]

    windower = Windower(WindowConfig(size=3), odometry, NAMES)
    queries = [windower.query(i, sets[i], observe) for i in range(6)]
    assert observed == []  # every earlier frame was some query's newest
    assert [q.frames for q in queries] == [[0], [0, 1], [0, 1, 2], [3], [2, 4], [4, 5]]
    assert [q.without_odometry for q in queries] == [0, 0, 0, 2, 1, 1]
    # the camera moves, the cup stays: one object, where the newest camera sees it
    assert len(queries[2].observations) == 1
    np.testing.assert_allclose(queries[2].observations.ellipsoids.centers[0], [-0.2, 0.0, 2.0], atol=1e-12)
    strided = Windower(WindowConfig(size=2, step=2), [shift(0.0)] * 6, NAMES)
    assert strided.query(5, sets[5], observe).frames == [3, 5] and observed == [3]
