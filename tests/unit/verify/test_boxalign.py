import numpy as np
from scipy.spatial.transform import Rotation

from clipclique.config import make_config
from clipclique.pipeline import index_map, localize
from clipclique.pose.distance import pose_errors
from clipclique.sim.poses import look_at
from clipclique.types import Camera, Ellipsoids, Hypothesis, Map, Observations, Pose
from clipclique.verify import boxalign
from clipclique.verify.projection import project

CAMERA = Camera(np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]), 640, 480)


def desk(count=4, seed=0):
    """`count` objects of 5-15 cm on a desk seen from 1.5 m, the true pose, and observations whose detection
    boxes are the landmarks' projected boxes under it."""
    rng = np.random.default_rng(seed)
    centers = np.column_stack((rng.uniform(-0.5, 0.5, count), rng.uniform(-0.3, 0.3, count),
                               rng.uniform(0, 0.2, count)))
    axes = rng.uniform(0.05, 0.15, (count, 3))
    rotations = Rotation.random(count, random_state=seed).as_matrix()
    map = Map(Ellipsoids(centers, axes, rotations), np.arange(count), [f"c{i}" for i in range(count)], [""] * count,
              np.arange(count))
    truth = look_at(np.array([0.3, -1.2, 0.9]), np.array([0.0, 0.0, 0.1]))
    seen = project(map.ellipsoids, truth.rotation[None], truth.translation[None], CAMERA)
    assert seen.visible.all()
    local = truth.inverse()
    observations = Observations(Ellipsoids(local.apply(centers), axes, local.rotation @ rotations), np.arange(count),
                                None, np.arange(count), np.arange(count), boxes=seen.boxes[0], camera=CAMERA)
    return map, observations, truth


def perturbed(pose, metres=0.3, degrees=3.0, seed=1):
    rng = np.random.default_rng(seed)
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    turn = Rotation.from_rotvec(np.deg2rad(degrees) * axis / np.linalg.norm(axis)).as_matrix()
    return Pose(pose.rotation @ turn, pose.translation + metres * direction / np.linalg.norm(direction))


def test_box_alignment_recovers_a_pose_a_clique_left_loose():
    map, observations, truth = desk()
    start = perturbed(truth)
    hypothesis = Hypothesis(start, np.column_stack((np.arange(4), np.arange(4))), 4.0, verification=1.0)
    assert pose_errors(start, truth)[0] > 0.25
    [refined] = boxalign.refine_hypotheses([hypothesis], observations, map, steps=15, scale=10.0)
    translation, rotation = pose_errors(refined.pose, truth)
    assert translation < 0.05 and np.rad2deg(rotation) < 0.5
    assert refined.verification == 1.0 and refined.correspondences is hypothesis.correspondences


def test_the_cost_never_rises_and_disagreeing_boxes_leave_the_pose_bounded():
    map, observations, truth = desk(seed=3)
    rng = np.random.default_rng(4)
    pairs = np.column_stack((np.arange(4), np.arange(4)))
    shuffled = Observations(observations.ellipsoids, observations.class_ids, None, observations.instance_ids,
                            observations.detection_index, boxes=observations.boxes[[2, 3, 0, 1]], camera=CAMERA)
    for obs in (observations, shuffled):
        start = perturbed(truth, seed=int(rng.integers(100)))
        problem = boxalign._problem([Hypothesis(start, pairs, 4.0)], obs, map, None)
        rot, trans, before, after = boxalign.solve(problem, start.rotation[None], start.translation[None], 5, 10.0,
                                                 CAMERA)
        assert after[0] <= before[0]
        [kept] = boxalign.refine_hypotheses([Hypothesis(start, pairs, 4.0)], obs, map, steps=5, scale=10.0)
        moved, turned = pose_errors(kept.pose, start)
        assert moved < boxalign.MAX_MOVE_M and turned < boxalign.MAX_TURN_RAD


def test_too_few_boxed_pairs_or_no_steps_leave_the_hypotheses_alone():
    map, observations, truth = desk()
    start = perturbed(truth)
    few = Hypothesis(start, np.array([[0, 0], [1, 1]]), 2.0)
    assert boxalign.refine_hypotheses([few], observations, map, steps=5, scale=10.0)[0] is few
    whole = Hypothesis(start, np.column_stack((np.arange(4), np.arange(4))), 4.0)
    assert boxalign.refine_hypotheses([whole], observations, map, steps=0, scale=10.0)[0] is whole
    no_boxes = Observations(observations.ellipsoids, observations.class_ids, None, observations.instance_ids,
                            observations.detection_index)
    assert boxalign.refine_hypotheses([whole], no_boxes, map, steps=5, scale=10.0)[0] is whole


def test_a_side_cut_by_the_image_border_is_left_out():
    map, observations, truth = desk()
    boxes = observations.boxes.copy()
    boxes[0, 0] = 0.0
    cut = Observations(observations.ellipsoids, observations.class_ids, None, observations.instance_ids,
                       observations.detection_index, boxes=boxes, camera=CAMERA)
    pairs = np.column_stack((np.arange(4), np.arange(4)))
    problem = boxalign._problem([Hypothesis(truth, pairs, 4.0)], cut, map, None)
    assert problem.sides[0].tolist() == [0.0, 1.0, 1.0, 1.0] and problem.sides[1:].all()
    [refined] = boxalign.refine_hypotheses([Hypothesis(perturbed(truth), pairs, 4.0)], cut, map, steps=15, scale=10.0)
    assert pose_errors(refined.pose, truth)[0] < 0.05


def test_in_localize_the_lever_at_0_changes_nothing_and_on_it_sharpens_the_top_pose(monkeypatch):
    """Eight objects whose observed centres carry 3 cm of noise, their boxes exact. At 0 the refinement is
    never called (so the results are those of the pipeline without it)."""
    map, observations, truth = desk(count=8, seed=5)
    rng = np.random.default_rng(6)
    noisy = Observations(Ellipsoids(observations.ellipsoids.centers + rng.normal(scale=0.03, size=(8, 3)),
                                    observations.ellipsoids.axes, observations.ellipsoids.rotations),
                         observations.class_ids, None, observations.instance_ids, observations.detection_index,
                         boxes=observations.boxes, camera=CAMERA)
    results = {}
    for name, overrides in {"off": {"pose.box_refine_steps": 0}, "prior": {"pose.box_refine_steps": 3},
                            "on": {"pose.box_refine_steps": 5, "pose.box_refine_centre_m": 0.0}}.items():
        config = make_config("clipclique", overrides={"similarity.alpha": 0.0} | overrides)
        results[name] = localize(noisy, index_map(map, config), config)
    config = make_config("clipclique", overrides={"similarity.alpha": 0.0, "pose.box_refine_steps": 0})

    def never(*args, **kwargs):
        raise AssertionError("box refinement called with pose.box_refine_steps = 0")

    monkeypatch.setattr(boxalign, "refine_hypotheses", never)
    untouched = localize(noisy, index_map(map, config), config).hypotheses
    off, prior, on = (results[name].hypotheses for name in ("off", "prior", "on"))
    assert len(untouched) == len(off) == len(prior) == len(on) > 0
    for a, b in zip(untouched, off):
        assert np.array_equal(a.pose.matrix(), b.pose.matrix()) and np.array_equal(a.correspondences, b.correspondences)
        assert a.verification == b.verification
    before = pose_errors(off[0].pose, truth)[0]
    assert before > 0.03
    assert pose_errors(prior[0].pose, truth)[0] < 0.75 * before  # the noisy centres' prior holds it back a little
    assert pose_errors(on[0].pose, truth)[0] < 0.01  # the exact boxes alone


def test_a_repeated_hypothesis_is_refined_once_and_alike():
    map, observations, truth = desk()
    pairs = np.column_stack((np.arange(4), np.arange(4)))
    start, other = perturbed(truth), perturbed(truth, seed=2)
    copy = Pose(start.rotation.copy(), start.translation.copy())
    hypotheses = [Hypothesis(start, pairs, 4.0, verification=3.0), Hypothesis(other, pairs, 4.0),
                  Hypothesis(copy, pairs.copy(), 3.0, verification=2.0)]
    assert len(boxalign._distinct(hypotheses)[0]) == 2
    first, second, again = boxalign.refine_hypotheses(hypotheses, observations, map, steps=15, scale=10.0)
    assert np.array_equal(first.pose.matrix(), again.pose.matrix()) and pose_errors(first.pose, truth)[0] < 0.05
    assert again.score == 3.0 and again.verification == 2.0 and pose_errors(second.pose, truth)[0] < 0.05
