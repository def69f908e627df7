"""Verifying pose hypotheses in the image: the score, RANSAC/PROSAC by projected overlap, re-ranking."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tolerance import assert_close

from clipclique.config import VerificationConfig, make_config
from clipclique.errors import ClipcliqueError
from clipclique.inliers import consensus
from clipclique.pipeline import index_map, localize
from clipclique.pose.stack import Stack
from clipclique.sim.poses import look_at
from clipclique.sim.synthetic import SIMULATED_CAMERA, synthetic_map, synthetic_query
from clipclique.types import Ellipsoids, Hypothesis, Map, Observations, Pose
from clipclique.verify import verification
from clipclique.verify.projection import box_area, box_iou, project
from clipclique.verify.ranking import RANK_DECIMALS
from clipclique.verify.verification import verify


def room() -> tuple[Map, Pose, Observations]:
    """Six boxes of furniture on a 4 x 3 m floor seen from 3.5 m away; the detections are the true
    projections, and the observed centres the true ones (nothing else to blame)."""
    centers = np.array([[0.0, 0.0, 0.4], [1.2, 0.3, 0.5], [-1.1, 0.6, 0.3], [0.5, 1.3, 0.8], [-0.6, -0.8, 0.4],
                        [1.5, -0.9, 0.6]])
    axes = np.array([[0.4, 0.3, 0.4], [0.3, 0.3, 0.5], [0.5, 0.2, 0.3], [0.3, 0.4, 0.2], [0.25, 0.25, 0.4],
                     [0.35, 0.3, 0.3]])
    map = Map(Ellipsoids(centers, axes, np.tile(np.eye(3), (6, 1, 1))), np.array([0, 1, 2, 0, 1, 2]),
              ["chair", "table", "sofa"], ["x"] * 6, np.arange(1, 7))
    pose = look_at(np.array([0.2, -3.5, 1.6]), np.array([0.1, 0.2, 0.4]))
    seen = project(map.ellipsoids, pose.rotation[None], pose.translation[None], SIMULATED_CAMERA)
    assert seen.visible.all()
    observations = Observations(map.ellipsoids.transformed(pose.inverse()), map.class_ids.copy(), None,
                                map.instance_ids.copy(), np.arange(6), seen.boxes[0], None, SIMULATED_CAMERA)
    return map, pose, observations


def hypothesis(pose: Pose, count: int = 6) -> Hypothesis:
    return Hypothesis(pose, np.column_stack((np.arange(count), np.arange(count))), 0.0)


def test_a_correct_pose_scores_higher_than_one_a_metre_off():
    map, truth, observations = room()
    off = [Pose(truth.rotation, truth.translation + shift)
           for shift in ([1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], truth.rotation @ [0, 0, 1.0])]
    checked = verify([hypothesis(truth), *(hypothesis(p) for p in off)], observations, map)
    assert checked.score[0] == pytest.approx(6.0)  # six perfect overlaps, nothing missed
    assert checked.missed[0] == 0 and checked.depth_error[0] == pytest.approx(0.0, abs=1e-9)
    assert (checked.score[1:] < 1.0).all(), checked.score  # at 3.5 m, a metre moves the boxes off their detections
    assert (checked.mean_iou[1:] < 0.35).all()


def test_alike_hypotheses_are_verified_once_and_get_the_same_figures():
    map, truth, observations = room()
    poses = [truth, Pose(truth.rotation, truth.translation + [0.3, 0, 0]),
             Pose(truth.rotation, truth.translation + [0, 0.4, 0.1])]
    pool = [hypothesis(poses[i], count) for i, count in ((0, 6), (1, 6), (0, 6), (2, 5), (1, 6), (0, 4))]
    group = np.array([0, 1, 0, 2, 1, 3])
    checked, distinct = verify(pool, observations, map), verify([pool[i] for i in (0, 1, 3, 5)], observations, map)
    for name in verification._PER_HYPOTHESIS:
        assert_close(getattr(checked, name), getattr(distinct, name)[group])
    assert checked.score[0] == checked.score[2] != checked.score[5]  # one pose, fewer pairs: not alike
    assert len(np.unique(checked.score)) == 4


def test_the_maps_kept_spreads_verify_as_the_landmarks_in_range_alone():
    """`verify_stack` with the whole map's spreads (what `index_map` keeps) gives the figures it gives computing them
    itself, and reads only the landmarks in range: spreads out of range changed change nothing, when some landmarks
    are out of range and when none is (then the changed spreads move the figures)."""
    map, truth, observations = room()
    poses = [truth, Pose(truth.rotation, truth.translation + [0.3, 0, 0]),
             Pose(truth.rotation, truth.translation + [0, 0.4, 0.1])]
    pool = Stack.of([hypothesis(pose, count) for pose, count in zip(poses, (6, 5, 4))])
    spreads = index_map(map, make_config("clipclique")).spreads
    for max_depth in (8.0, 3.0):  # every landmark in range; the far ones out
        seen = dataclasses.replace(observations, camera=dataclasses.replace(observations.camera, max_depth=max_depth))
        in_range = verification._in_range(map.ellipsoids.centers, map.ellipsoids.axes, pool.translations, max_depth)
        assert in_range.sum() == (6 if max_depth > 4 else 3)
        changed = spreads.copy()
        changed[~in_range] *= 4.0
        changed[in_range & (max_depth > 4)] *= 4.0
        kept, alone, out_of_range = (verification.verify_stack(pool, seen, map, VerificationConfig(), spreads),
                                     verification.verify_stack(pool, seen, map, VerificationConfig()),
                                     verification.verify_stack(pool, seen, map, VerificationConfig(), changed))
        for name in verification._PER_HYPOTHESIS:
            assert_close(getattr(kept, name), getattr(alone, name))
            if max_depth < 4:
                assert_close(getattr(kept, name), getattr(out_of_range, name))
        assert (max_depth > 4) == (not np.allclose(kept.overlap, out_of_range.overlap))


def test_a_landmark_the_pose_expects_but_nothing_detected_is_missed():
    map, truth, observations = room()
    keep = np.arange(5)  # the sixth object goes undetected
    partial = Observations(observations.ellipsoids.subset(keep), observations.class_ids[keep], None,
                           observations.instance_ids[keep], keep, observations.boxes[keep], None, observations.camera)
    by_number = VerificationConfig(missed_full_area=0.0, missed_share_from=0.0)
    checked = verify([hypothesis(truth, 5)], partial, map, by_number)
    assert checked.missed[0] == 1
    assert checked.score[0] == pytest.approx(5.0 - VerificationConfig().missed_weight)


def test_a_pose_expecting_more_than_missed_share_from_pays_for_the_share_it_missed():
    """Five of the room's landmarks are large enough to expect (the fourth projects to 1,133 px), the sixth
    goes undetected: one of five missed costs 3/5 of a landmark from 3 on, in full from 5 or with 0 (off)."""
    map, truth, observations = room()
    keep = np.arange(5)
    partial = Observations(observations.ellipsoids.subset(keep), observations.class_ids[keep], None,
                           observations.instance_ids[keep], keep, observations.boxes[keep], None, observations.camera)
    weight = VerificationConfig().missed_weight
    for share_from, cost in ((3.0, 0.6), (4.0, 0.8), (5.0, 1.0), (8.0, 1.0), (0.0, 1.0)):
        checked = verify([hypothesis(truth, 5)], partial, map,
                         VerificationConfig(missed_full_area=0.0, missed_share_from=share_from))
        assert checked.missed[0] == 1 and checked.expected_evidence[0] == pytest.approx(5.0)
        assert checked.score[0] == pytest.approx(5.0 - weight * cost)
    assert verify([hypothesis(truth, 5)], partial, map).expected_evidence[0] < 3  # sized: 1.2, no share by default


def test_the_missed_share_ranks_a_pose_into_a_crowd_above_one_past_it():
    """A pose looking at a cluttered desk overlaps more but misses 8 of the 12 objects it expects (a detector
    misses most small things); a wrong one looking past the desk misses 1 of 2. By number the wrong one wins,
    by share the right one; a pose expecting at most missed_share_from pays the same either way."""
    overlap, missed, expected = np.array([3.0, 2.5]), np.array([8.0, 1.0]), np.array([12.0, 2.0])
    by_number = overlap - verification.missed_cost(missed, expected, VerificationConfig(missed_share_from=0.0))
    by_share = overlap - verification.missed_cost(missed, expected, VerificationConfig())
    np.testing.assert_allclose(by_number, [1.0, 2.25])
    np.testing.assert_allclose(by_share, [3.0 - 0.25 * 8 * 3 / 12, 2.25])
    assert by_share.argmax() == 0 and by_number.argmax() == 1
    assert VerificationConfig().missed_share_from == 3.0


def test_the_missed_share_is_on_in_clipclique_and_off_in_the_paper_preset_and_baselines():
    assert make_config("clipclique").verification.missed_share_from == 3.0
    for method in ("clipclique-paper", "sh", "xview", "cliploc"):
        assert make_config(method).verification.missed_share_from == 0.0


def test_a_missed_landmark_costs_by_its_projected_size():
    """Detectors miss small objects most: an undetected landmark costs in full only when its box covers
    missed_full_area of the image. The sixth box covers 2% of this image: a third of the cost at a
    sixteenth, all of it at 1.5%, a fiftieth at 100%."""
    map, truth, observations = room()
    keep = np.arange(5)
    partial = Observations(observations.ellipsoids.subset(keep), observations.class_ids[keep], None,
                           observations.instance_ids[keep], keep, observations.boxes[keep], None, observations.camera)
    x0, y0, x1, y1 = observations.boxes[5]
    share = (x1 - x0) * (y1 - y0) / (SIMULATED_CAMERA.width * SIMULATED_CAMERA.height)
    assert 0.02 < share < 0.021
    weight = VerificationConfig().missed_weight
    for full, cost in ((0.0625, share / 0.0625), (0.015, 1.0), (1.0, share)):
        checked = verify([hypothesis(truth, 5)], partial, map,
                         VerificationConfig(missed_full_area=full, missed_share_from=0.0))
        assert checked.missed[0] == 1
        assert checked.missed_evidence[0] == pytest.approx(cost)
        assert checked.score[0] == pytest.approx(5.0 - weight * cost)


def test_depth_disagreement_along_the_ray_lowers_the_score():
    map, truth, observations = room()
    deeper = dataclasses.replace(observations, ellipsoids=Ellipsoids(observations.ellipsoids.centers * [1, 1, 1.1],
                                                                     observations.ellipsoids.axes,
                                                                     observations.ellipsoids.rotations))
    near, far = verify([hypothesis(truth)], observations, map), verify([hypothesis(truth)], deeper, map)
    assert far.depth_error[0] > 0.2 and far.score[0] < near.score[0] - 2.0


def test_ransac_verified_by_overlap_finds_the_true_correspondences():
    map, truth, observations = room()
    wrong = np.column_stack((np.arange(6), (np.arange(6) + 3) % 6))  # same classes, wrong objects
    candidates = np.vstack((np.column_stack((np.arange(6), np.arange(6))), wrong))
    image = consensus.ImageEvidence(map.ellipsoids, observations.boxes, observations.camera, 0.3)
    found = consensus.sample_consensus(observations.ellipsoids.centers, map.ellipsoids.centers, candidates,
                                     np.ones(len(candidates)), iterations=500, threshold=0.5,
                                     rng=np.random.default_rng(0), image=image)
    np.testing.assert_array_equal(candidates[found.inlier_sets[0]], np.column_stack((np.arange(6), np.arange(6))))
    assert found.scores[0] == pytest.approx(6.0)  # summed IoU of six perfect overlaps


def test_overlap_verification_needs_boxes_and_centres_do_not():
    rng = np.random.default_rng(2)
    map = synthetic_map(rng)
    observations, _ = synthetic_query(map, rng)
    bare = dataclasses.replace(observations, boxes=None, camera=None)
    overlap, centers = make_config("sh"), make_config("sh", overrides=["inliers.verification=centers"])
    with pytest.raises(ClipcliqueError, match="inliers.verification = overlap"):
        localize(bare, index_map(map, overlap), overlap)
    result = localize(bare, index_map(map, centers), centers)
    assert result.hypotheses and result.hypotheses[0].confidence is None  # nothing to verify in the image


def test_rerank_orders_every_methods_hypotheses_by_verification():
    """With a pool of top_n the re-ranking reorders the same hypotheses; with a larger pool (the default 50)
    it keeps the top_n best verified of more, so the best it keeps is at least as good."""
    rng = np.random.default_rng(6)
    map = synthetic_map(rng)
    for method in ("clipclique", "cliploc"):
        plain = make_config(method, overrides=["inliers.rerank=none"])
        reordered = make_config(method, overrides=["inliers.rerank=verification", "inliers.rerank_pool=5"])
        pooled = make_config(method, overrides=["inliers.rerank=verification"])
        wide = make_config(method, overrides=["inliers.rerank=none", "top_n=50"])
        assert pooled.inliers.rerank_pool == 50
        larger_pools = 0
        for _ in range(4):
            observations, _ = synthetic_query(map, rng)
            before, after, more, all_fitted = (localize(observations, index_map(map, config), config).hypotheses
                                               for config in (plain, reordered, pooled, wide))
            scores = [h.verification for h in after]
            ranked = np.round(scores, RANK_DECIMALS).tolist()  # keys equal to RANK_DECIMALS tie: the pool's order
            assert ranked == sorted(ranked, reverse=True)
            assert sorted(h.verification for h in before) == sorted(scores)
            assert len(more) == len(after) and more[0].verification >= after[0].verification
            best = sorted(np.round([h.verification for h in all_fitted], RANK_DECIMALS).tolist(), reverse=True)[:5]
            assert np.round([h.verification for h in more], RANK_DECIMALS).tolist() == best
            larger_pools += len(all_fitted) > 5
        assert larger_pools > 0  # some frame's pool held more than the five it kept


@pytest.mark.parametrize(("override", "message"), [
    ("inliers.verification=ious", "inliers.verification = 'ious'; choose one of overlap, centers"),
    ("inliers.rerank=score", "inliers.rerank = 'score'; choose one of none, verification, confidence"),
    ("inliers.iou_threshold=1.5", "inliers.iou_threshold = 1.5; must be within"),
    ("min_confidence=-0.1", "min_confidence = -0.1; must be within"),
])
def test_verification_keys_are_checked(override, message):
    from clipclique.config import ConfigError

    with pytest.raises(ConfigError, match=message):
        make_config("sh", overrides=[override])


def numpy_group_medians(values, groups, sizes):
    """The group medians as numpy passes computed them before they were compiled: one lexsort, the middle pair."""
    ordered = values[np.lexsort((values, groups))]
    starts = np.cumsum(sizes) - sizes
    middle = (ordered[np.minimum(starts + (sizes - 1) // 2, len(ordered) - 1)]
              + ordered[np.minimum(starts + sizes // 2, len(ordered) - 1)]) if len(ordered) else np.zeros(len(sizes))
    return np.where(sizes > 0, middle / 2, np.inf)


def test_group_medians_are_numpys():
    rng = np.random.default_rng(0)
    for trial in range(500):
        sizes = rng.integers(0, 9, int(rng.integers(1, 7)))
        groups = np.repeat(np.arange(len(sizes)), sizes)
        values = rng.random(len(groups)) * 10.0 ** rng.uniform(-3, 3)
        if trial % 3 == 0:
            values = np.round(values, 1)  # ties
        expected = [np.median(values[groups == b]) if sizes[b] else np.inf for b in range(len(sizes))]
        assert_close(verification._group_medians(values, sizes), np.array(expected))
        if trial % 4 == 0 and len(values):  # signed zeros among ties, NaN: as the lexsort passes had them
            values[rng.random(len(values)) < 0.4] = rng.choice([0.0, -0.0, np.nan])
            assert_close(verification._group_medians(values, sizes), numpy_group_medians(values, groups, sizes))


def numpy_pair_measures(obs, lm, owner, slot, visible, projected, boxes, depth_gap, tolerance, sizes):
    """Overlap, mean IoU and median depth gap per hypothesis as numpy passes computed them before they were compiled."""
    at = np.maximum(slot[lm], 0)
    in_view = (slot[lm] >= 0) & visible[owner, at]
    iou = np.where(in_view, box_iou(boxes[obs], projected[owner, at]), 0.0)
    agreement = np.maximum(1.0 - depth_gap / tolerance, 0.0)
    overlap = np.bincount(owner, iou * agreement, minlength=len(sizes))
    mean_iou = np.bincount(owner, iou, minlength=len(sizes)) / np.maximum(sizes, 1)
    return overlap, mean_iou, numpy_group_medians(depth_gap, owner, sizes)


def test_the_compiled_pair_figures_are_the_numpy_passes():
    """Pairs out of range, out of view, boxes sharing edges or empty, depth gaps at and beyond the tolerance, NaN,
    and hypotheses left without a pair."""
    rng = np.random.default_rng(13)
    for trial in range(300):
        count, landmarks, detections = int(rng.integers(1, 8)), int(rng.integers(1, 12)), int(rng.integers(1, 9))
        sizes = rng.integers(0, 7, count)
        owner = np.repeat(np.arange(count), sizes)
        obs, lm = rng.integers(0, detections, len(owner)), rng.integers(0, landmarks, len(owner))
        slot = np.where(rng.random(landmarks) < 0.8, rng.permutation(landmarks), -1)
        corners = np.round(rng.uniform(0, 40, (count * landmarks + detections, 2, 2)))  # whole pixels: shared edges
        corners[::7, 1] = corners[::7, 0]  # empty boxes
        all_boxes = np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)
        projected, boxes = all_boxes[: count * landmarks].reshape(count, landmarks, 4), all_boxes[count * landmarks:]
        visible = rng.random((count, landmarks)) < 0.7
        depth_gap = np.round(rng.uniform(0, 1.2, len(owner)), 1)  # exactly at the tolerance (0.5), and ties
        if trial % 5 == 0 and len(depth_gap):
            depth_gap[rng.integers(len(depth_gap))] = np.nan
        got = verification._pair_measures(obs, lm, owner, slot, visible, projected, boxes, depth_gap, 0.5, sizes)
        for ours, theirs in zip(got, numpy_pair_measures(obs, lm, owner, slot, visible, projected, boxes, depth_gap,
                                                        0.5, sizes)):
            assert_close(ours, theirs)


def numpy_missed(boxes, visible, full_areas, class_ids, detected, detected_classes, min_pixels, explained_iou, full):
    """Missed landmarks, their evidence and the expected evidence as numpy passes computed them before they were
    compiled: the expected ones by a mask, each tested against every detection of its class, np.bincount sums."""
    area = box_area(boxes)
    expected = visible & (area >= min_pixels) & (area >= 0.5 * full_areas)
    hypothesis, landmark = np.nonzero(expected)
    explained = np.array([any(detected_classes[k] == class_ids[n] and box_iou(boxes[b, n], detected[k]) >= explained_iou
                              for k in range(len(detected))) for b, n in zip(hypothesis, landmark)], bool)
    weight = np.minimum(1.0, area[hypothesis, landmark] / full) if full > 0 else np.ones(len(hypothesis))
    return (np.bincount(hypothesis[~explained], minlength=len(expected)),
            np.bincount(hypothesis[~explained], weight[~explained], minlength=len(expected)),
            np.bincount(hypothesis, weight, minlength=len(expected)))


def test_the_compiled_missed_landmarks_are_the_numpy_passes():
    """Boxes at the pixel floor and at half their unclipped area, empty boxes, detections of other classes, IoU
    exactly at the threshold, landmarks as large as the full area and beyond, and full = 0 (every one counts 1)."""
    rng = np.random.default_rng(14)
    for trial in range(300):
        count, size, detections = int(rng.integers(1, 6)), int(rng.integers(0, 15)), int(rng.integers(0, 8))
        corners = np.round(rng.uniform(0, 80, (count * size + detections, 2, 2)))
        corners[::6, 1, 0] = corners[::6, 0, 0]  # empty boxes
        boxes = np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)
        projected, detected = boxes[: count * size].reshape(count, size, 4), boxes[count * size:]
        area = box_area(projected)
        full_areas = np.where(rng.random((count, size)) < 0.3, 2 * area, area * rng.uniform(0.5, 3, (count, size)))
        visible = rng.random((count, size)) < 0.8
        class_ids, detected_classes = rng.integers(0, 3, size), rng.integers(0, 3, detections)
        min_pixels, full = float(rng.choice([0.0, 100.0, 400.0])), float(rng.choice([0.0, 900.0, 2500.0]))
        explained_iou = float(rng.choice([0.0, 0.1, 0.5]))
        got = verification._missed_evidence(projected, visible, full_areas, class_ids, detected, detected_classes,
                                            min_pixels, explained_iou, full)
        for ours, theirs in zip(got, numpy_missed(projected, visible, full_areas, class_ids, detected, detected_classes,
                                                  min_pixels, explained_iou, full)):
            assert_close(ours, theirs)


def numpy_in_range(centers, axes, translations, max_depth):
    """Whether some camera may see each landmark, as the numpy expression had it before it was compiled."""
    distance = np.linalg.norm(centers[None] - translations[:, None], axis=2) - axes.max(axis=1)
    return (distance <= max_depth).any(axis=0)


def test_landmarks_in_range_are_those_numpys_norm_puts_in_range():
    """The compiled range test against the numpy expression it replaces, with landmarks exactly at the range, and
    NaN and infinite centres and axes."""
    rng = np.random.default_rng(1)
    for trial in range(300):
        count, cameras = int(rng.integers(1, 40)), int(rng.integers(1, 8))
        centers, translations = rng.normal(scale=3.0, size=(count, 3)), rng.normal(scale=2.0, size=(cameras, 3))
        axes = rng.uniform(0.01, 0.5, (count, 3))
        if trial % 2:  # on a grid: distances exactly at max_depth plus the size
            centers, translations, axes = np.round(centers), np.round(translations), np.round(axes * 4) / 4
        if trial % 3 == 0:
            axes[rng.integers(count), rng.integers(3)] = rng.choice([np.nan, np.inf])
            centers[rng.integers(count), rng.integers(3)] = rng.choice([np.nan, np.inf, -np.inf])
        max_depth = float(rng.choice([1.0, 2.0, 3.0]))
        with np.errstate(invalid="ignore"):
            expected = numpy_in_range(centers, axes, translations, max_depth)
        assert_close(verification._in_range(centers, axes, translations, max_depth), expected)


def test_the_distinct_hypotheses_and_landmarks_in_range_are_alikes_and_numpys():
    """`_distinct_in_range` against `stack.alike` of the poses' numbers and pairs, the numpy range test of the
    firsts' cameras, and their poses gathered: alike poses with other pairs, -0 against +0, NaN, no hypothesis."""
    from clipclique.pose.stack import alike

    rng = np.random.default_rng(5)
    for trial in range(200):
        count, landmarks = int(rng.integers(0, 9)), int(rng.integers(1, 30))
        rotations = rng.choice([-0.0, 0.0, 0.5, 1.0], size=(count, 3, 3))
        translations = rng.choice([0.0, 1.5, -2.0, np.nan], size=(count, 3)) if trial % 4 == 0 else \
            rng.choice([0.0, 1.5, -2.0], size=(count, 3))
        counts = rng.integers(0, 3, count).astype(np.int64)
        pairs = rng.integers(0, 2, (int(counts.sum()), 2)).astype(np.int64)
        centers, axes = rng.normal(scale=3.0, size=(landmarks, 3)), rng.uniform(0.01, 0.5, (landmarks, 3))
        group, firsts, nearby, kept_rotations, kept_translations = verification._distinct_in_range(
            rotations, translations, pairs, counts, centers, axes, 2.0)
        poses = np.concatenate((rotations.reshape(-1, 9), translations), axis=1)
        expected_group, expected_firsts = alike(poses, pairs, np.cumsum(counts) - counts, counts)
        assert_close(group, expected_group)
        assert_close(firsts, expected_firsts)
        with np.errstate(invalid="ignore"):
            expected_nearby = np.flatnonzero(numpy_in_range(centers, axes, translations[firsts], 2.0))
        assert_close(nearby, expected_nearby)
        np.testing.assert_array_equal(kept_rotations, rotations[firsts])  # gathered, not computed
        np.testing.assert_array_equal(kept_translations, translations[firsts])


def test_the_missed_costs_are_the_numpy_passes():
    """The compiled missed cost against numpy's: expected evidence below, at and above missed_share_from, 0, NaN and
    infinite, share 0 (off), weights of 0."""
    rng = np.random.default_rng(6)
    for trial in range(200):
        count = int(rng.integers(0, 12))
        missed = rng.choice([0.0, 0.5, 1.0, 2.75, np.nan, np.inf], size=count)
        expected = rng.choice([0.0, 1.0, 3.0, 4.5, 12.0, np.nan, np.inf], size=count)
        weight, share_from = float(rng.choice([0.0, 0.25, 1.5])), float(rng.choice([0.0, 0.5, 3.0]))
        with np.errstate(invalid="ignore"):
            cost = weight * missed
            numpy_cost = cost if share_from == 0 else cost * (share_from / np.maximum(expected, share_from))
            got = verification.missed_cost(missed, expected, VerificationConfig(missed_weight=weight,
                                                                                missed_share_from=share_from))
        assert_close(got, numpy_cost)


def test_the_verified_figures_are_the_kernels_passes():
    """`_verdicts` against its passes one by one (`_rows_pairs`, `_depths_along`, `_measures`, the numpy missed cost)
    and each hypothesis given its group's figures: groups in any order, hypotheses without pairs, none."""
    from clipclique.sim.poses import random_rotation

    rng = np.random.default_rng(16)
    for trial in range(150):
        count, landmarks, detections = int(rng.integers(0, 7)), int(rng.integers(1, 12)), int(rng.integers(1, 8))
        counts = rng.integers(0, 5, count).astype(np.int64)
        pairs = np.column_stack((rng.integers(0, detections, counts.sum()),
                                 rng.integers(0, landmarks, counts.sum()))).astype(np.int64)
        group = np.array([int(rng.integers(0, b + 1)) for b in range(count)], np.int64)
        group = np.unique(group, return_inverse=True)[1].astype(np.int64)  # each group numbered, some hypotheses alike
        firsts = np.array([np.flatnonzero(group == g)[0] for g in range(group.max() + 1)] if count else [], np.int64)
        rotations = np.array([random_rotation(rng) for _ in firsts]).reshape(-1, 3, 3)
        translations = rng.uniform(-3, 3, (len(firsts), 3))
        centers = rng.uniform(-3, 3, (landmarks, 3))
        nearby = np.sort(rng.choice(landmarks, int(rng.integers(1, landmarks + 1)), replace=False))
        corners = np.round(rng.uniform(0, 60, (len(firsts) * len(nearby) + detections, 2, 2)))
        all_boxes = np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)
        projected = all_boxes[: len(firsts) * len(nearby)].reshape(len(firsts), len(nearby), 4)
        boxes = all_boxes[len(firsts) * len(nearby):]
        visible = rng.random((len(firsts), len(nearby))) < 0.7
        full_areas = box_area(projected) * rng.uniform(0.5, 3, visible.shape)
        observed = np.round(rng.uniform(0, 3, (detections, 3)), 1)
        class_ids, detected_classes = rng.integers(0, 3, landmarks), rng.integers(0, 3, detections)
        weight, share_from = float(rng.choice([0.0, 0.25])), float(rng.choice([0.0, 3.0]))
        settings = (0.5, float(rng.choice([0.0, 100.0])), 0.1, float(rng.choice([0.0, 900.0])))
        got = verification._verdicts(group, firsts, pairs, counts, rotations, translations, centers, nearby, landmarks,
                                     visible, projected, full_areas, boxes, observed, class_ids, detected_classes,
                                     *settings, weight, share_from)
        obs, lm, owner, sizes = verification._rows_pairs(pairs, counts, firsts)
        depths = verification._depths_along(centers, lm, translations, rotations, owner)
        overlap, mean_iou, depth_error, missed, evidence, expected = verification._measures(
            obs, lm, owner, nearby, landmarks, visible, projected, full_areas, boxes, observed[:, 2], depths, class_ids,
            detected_classes, sizes, *settings)
        cost = weight * evidence
        score = overlap - (cost if share_from == 0 else cost * (share_from / np.maximum(expected, share_from)))
        for ours, theirs in zip(got, (score, overlap, mean_iou, missed, evidence, expected, depth_error), strict=True):
            assert_close(ours, theirs[group])


def test_the_figures_in_one_call_are_the_numpy_passes():
    """`_measures` (the landmarks' columns, the depth gaps, then the pair figures and the missed landmarks in one
    compiled call) against the numpy passes: landmarks out of range, depth gaps of 0, NaN and exactly at the
    tolerance, boxes sharing edges or empty, hypotheses without a pair."""
    rng = np.random.default_rng(15)
    for trial in range(300):
        count, landmarks, detections = int(rng.integers(1, 7)), int(rng.integers(1, 12)), int(rng.integers(0, 8))
        sizes = rng.integers(0, 6, count)
        owner = np.repeat(np.arange(count), sizes)
        obs = rng.integers(0, max(detections, 1), len(owner))
        lm = rng.integers(0, landmarks, len(owner))
        nearby = np.sort(rng.choice(landmarks, int(rng.integers(1, landmarks + 1)), replace=False))
        corners = np.round(rng.uniform(0, 60, (count * len(nearby) + max(detections, 1), 2, 2)))
        corners[::6, 1] = corners[::6, 0]  # empty boxes
        all_boxes = np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)
        projected = all_boxes[: count * len(nearby)].reshape(count, len(nearby), 4)
        boxes = all_boxes[count * len(nearby):]
        visible = rng.random((count, len(nearby))) < 0.7
        area = box_area(projected)
        full_areas = np.where(rng.random(area.shape) < 0.3, 2 * area, area * rng.uniform(0.5, 3, area.shape))
        observed_depths = np.round(rng.uniform(0, 3, (len(boxes), 3)), 1)[:, 2]  # a strided column, as the centres'
        landmark_depths = np.round(rng.uniform(0, 3, len(owner)), 1)  # gaps of 0 and exactly at 0.5
        if trial % 5 == 0 and len(owner):
            landmark_depths[rng.integers(len(owner))] = np.nan
        class_ids, detected_classes = rng.integers(0, 3, landmarks), rng.integers(0, 3, len(boxes))
        min_pixels, full = float(rng.choice([0.0, 100.0])), float(rng.choice([0.0, 900.0]))
        got = verification._measures(obs, lm, owner, nearby, landmarks, visible, projected, full_areas, boxes,
                                    observed_depths, landmark_depths, class_ids, detected_classes, sizes, 0.5,
                                    min_pixels, 0.1, full)
        slot = np.full(landmarks, -1)
        slot[nearby] = np.arange(len(nearby))
        depth_gap = np.abs(observed_depths[obs] - landmark_depths)
        expected = (*numpy_pair_measures(obs, lm, owner, slot, visible, projected, boxes, depth_gap, 0.5, sizes),
                    *numpy_missed(projected, visible, full_areas, class_ids[nearby], boxes, detected_classes,
                                  min_pixels,
                                  0.1, full))
        for ours, theirs in zip(got, expected, strict=True):
            assert_close(ours, theirs)


def test_the_compiled_landmark_depths_are_einsums():
    """`_depths_along` against the einsum of the gathered offsets and optical axes: random poses and hand-made
    entries (-0, NaN, infinities, a landmark at the camera, pairs sharing a landmark or a pose) and no pairs."""
    from clipclique.sim.poses import random_rotation
    from clipclique.verify.verification import _depths_along

    rng = np.random.default_rng(9)
    for pairs in (0, 1, 5, 200):
        for trial in range(20):
            poses, landmarks = int(rng.integers(1, 6)), int(rng.integers(1, 30))
            rotations = np.array([random_rotation(rng) for _ in range(poses)])
            translations, centers = rng.uniform(-5, 5, (poses, 3)), rng.uniform(-5, 5, (landmarks, 3))
            lm, owner = rng.integers(0, landmarks, pairs), np.sort(rng.integers(0, poses, pairs))
            if trial % 2:
                rotations[0, :, 2] = [-0.0, 0.0, 1.0]
                centers[0] = translations[0]  # offsets of 0: products of -0
                centers[-1, 1] = np.nan
                centers[landmarks // 2, 0] = np.inf
                translations[-1, 2] = -np.inf if trial % 4 == 1 else 1e308
            with np.errstate(invalid="ignore", over="ignore"):
                expected = np.einsum("mi,mi->m", centers[lm] - translations[owner], rotations[owner, :, 2])
                got = _depths_along(centers, lm, translations, rotations, owner)
            assert_close(got, expected)


def test_the_rows_pairs_are_the_taken_stacks():
    """`_rows_pairs` against `Stack.take(rows)`'s pairs, owners and counts: rows in any order, repeated, hypotheses
    without pairs, no rows, and an empty stack."""
    from clipclique.verify.verification import _rows_pairs

    rng = np.random.default_rng(4)
    for trial in range(40):
        count = int(rng.integers(0, 9))
        counts = rng.integers(0, 6, count).astype(np.int64)
        stack = Stack(rotations=np.zeros((count, 3, 3)), translations=np.zeros((count, 3)),
                      pairs=rng.integers(0, 50, (int(counts.sum()), 2)).astype(np.int64), counts=counts,
                      scores=np.zeros(count), conditioning=np.zeros(count))
        rows = rng.integers(0, count, int(rng.integers(0, 2 * count + 1))) if count else np.zeros(0, np.int64)
        taken = stack.take(rows)
        obs, lm, owner, sizes = _rows_pairs(stack.pairs, stack.counts, rows)
        for ours, theirs in ((obs, taken.pairs[:, 0]), (lm, taken.pairs[:, 1]), (owner, taken.owners()),
                             (sizes, taken.counts)):
            assert ours.dtype == np.int64
            assert_close(ours, theirs)
