import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.pose import refine as refine_module
from clipclique.pose.distance import pose_errors
from clipclique.pose.refine import nearby_pairs, nearby_pairs_of, refine
from clipclique.pose.stack import Stack
from clipclique.types import Ellipsoids, Hypothesis, Map, Observations, Pose


def desk(rng):
    """Eight objects on a 2 m desk seen from 1.5 m; the camera's true pose; the observations (2 cm noise)."""
    centers = np.column_stack((rng.uniform(0, 2, 8), rng.uniform(0, 0.8, 8), np.full(8, 0.75)))
    axes = np.full((8, 3), 0.05)
    map = Map(Ellipsoids(centers, axes, np.tile(np.eye(3), (8, 1, 1))), np.arange(8), [f"c{i}" for i in range(8)],
              [""] * 8, np.arange(8))
    truth = Pose(Rotation.from_euler("xyz", [-2.2, 0.1, 0.3]).as_matrix(), np.array([1.0, 2.0, 1.5]))
    seen = truth.inverse().apply(centers) + rng.normal(scale=0.02, size=(8, 3))
    observations = Observations(Ellipsoids(seen, axes.copy(), np.tile(np.eye(3), (8, 1, 1))), np.arange(8), None,
                                np.arange(8), np.arange(8))
    return map, observations, truth


def test_refit_on_every_nearby_similar_landmark_corrects_a_poorly_fixed_pose():
    rng = np.random.default_rng(0)
    map, observations, truth = desk(rng)
    # a clique of three objects whose pose is 8 degrees and 15 cm off: a metre-scale error over the desk
    off = Pose(Rotation.from_euler("z", 0.14).as_matrix(), np.array([0.15, 0.0, 0.0])).compose(truth)
    similarity = np.eye(8)
    hypothesis = Hypothesis(off, np.array([[0, 0], [1, 1], [2, 2]]), 3.0)
    assert pose_errors(off, truth)[0] > 0.15
    refine([hypothesis], observations, map, similarity, radius=0.3, weights="none")
    assert pose_errors(hypothesis.pose, truth)[0] < 0.05
    assert (len(hypothesis.correspondences) > 3
            and (hypothesis.correspondences[:, 0] == hypothesis.correspondences[:, 1]).all())


def test_only_similar_landmarks_within_the_radius_are_taken_one_to_one():
    rng = np.random.default_rng(1)
    map, observations, truth = desk(rng)
    similarity = np.eye(8)
    similarity[3] = 0.0  # observation 3 resembles nothing: never paired
    pairs = nearby_pairs(truth, observations, map, similarity, radius=0.3)
    assert sorted(pairs[:, 0].tolist()) == [0, 1, 2, 4, 5, 6, 7]
    assert (pairs[:, 0] == pairs[:, 1]).all()
    assert len(nearby_pairs(truth, observations, map, np.ones((8, 8)), radius=0.3)[:, 1]) == 8  # one-to-one
    assert len(nearby_pairs(truth, observations, map, similarity, radius=0.001)) == 0


def dense_nearby_pairs(pose, observations, map, similarity, radius):
    """The (K, N) distance matrix version: every pair tested, nearest first, ties in row-major order. The
    observations moved as `refine._apply_poses` adds, r0 x0 + r1 x1 + r2 x2 + t: noise-free observations lie ~1e-16 from
    their landmarks, and the order of such distances is the rounding's."""
    x, r = observations.ellipsoids.centers, pose.rotation
    moved = x[:, :1] * r[:, 0] + x[:, 1:2] * r[:, 1] + x[:, 2:] * r[:, 2] + pose.translation
    distance = np.linalg.norm(moved[:, None] - map.ellipsoids.centers[None], axis=-1)
    allowed = (distance < radius) & (similarity > 0)
    order = np.argsort(np.where(allowed, distance, np.inf), axis=None, kind="stable")[: int(allowed.sum())]
    used_obs, used_lm, pairs = set(), set(), []
    for k, n in zip(*np.unravel_index(order, distance.shape)):
        if k not in used_obs and n not in used_lm:
            used_obs.add(k)
            used_lm.add(n)
            pairs.append((k, n))
    return np.array(pairs, np.int64).reshape(-1, 2)


@pytest.mark.parametrize("dense_pairs", [0, refine_module.DENSE_PAIRS], ids=["kd-tree join", "every pair tested"])
def test_the_kd_tree_search_pairs_exactly_as_the_dense_distance_matrix(dense_pairs, monkeypatch):
    monkeypatch.setattr(refine_module, "DENSE_PAIRS", dense_pairs)
    rng = np.random.default_rng(3)
    for trial in range(200):
        count, seen = int(rng.integers(1, 60)), int(rng.integers(1, 15))
        centers = rng.uniform(0, 1.5, (count, 3))
        if trial % 3 == 0:  # copies of landmarks on one spot and on a grid: distance ties to break alike
            centers[count // 2:] = centers[: count - count // 2]
            centers = np.round(centers * 4) / 4
        axes = np.full((count, 3), 0.05)
        map = Map(Ellipsoids(centers, axes, np.tile(np.eye(3), (count, 1, 1))), np.zeros(count, np.int64), ["c"],
                  [""] * count,
                  np.arange(count))
        pose = Pose(Rotation.random(random_state=trial).as_matrix(), rng.normal(size=3))
        picked = rng.integers(0, count, seen)
        local = pose.inverse().apply(centers[picked]) + rng.normal(scale=0.1 if trial % 2 else 0.0, size=(seen, 3))
        if trial % 5 == 0 and dense_pairs:  # an observation and a landmark without a place: near nothing
            local[0], centers[-1, trial % 3] = np.nan, np.nan  # (a KD-tree holds no NaN)
        observations = Observations(Ellipsoids(local, np.full((seen, 3), 0.05), np.tile(np.eye(3), (seen, 1, 1))),
                                    np.zeros(seen, np.int64), None, np.arange(seen), np.arange(seen))
        similarity = np.where(rng.random((seen, count)) < 0.7, rng.random((seen, count)), 0.0)
        radius = float(rng.choice([0.05, 0.3, 0.8, 0.25]))
        expected = dense_nearby_pairs(pose, observations, map, similarity, radius)
        assert np.array_equal(nearby_pairs(pose, observations, map, similarity, radius), expected)


def test_a_refit_on_fewer_objects_than_the_clique_leaves_it_alone():
    rng = np.random.default_rng(2)
    map, observations, truth = desk(rng)
    far = Pose(truth.rotation, truth.translation + [3.0, 0, 0])
    hypothesis = Hypothesis(far, np.array([[0, 0], [1, 1], [2, 2]]), 3.0)
    refine([hypothesis], observations, map, np.eye(8), radius=0.3, weights="none")
    assert hypothesis.pose is far


def test_a_batch_of_poses_pairs_each_as_the_dense_distance_matrix_alone():
    rng = np.random.default_rng(3)
    map, observations, truth = desk(rng)
    doubled = Map(Ellipsoids(np.repeat(map.ellipsoids.centers, 2, axis=0), np.repeat(map.ellipsoids.axes, 2, axis=0),
                             np.tile(np.eye(3), (16, 1, 1))), np.repeat(map.class_ids, 2), map.class_names, [""] * 16,
                  np.arange(16))  # every landmark twice: exact distance ties, broken by landmark order
    similarity = rng.random((8, 16)) * (rng.random((8, 16)) < 0.7)
    poses = [truth] + [Pose(Rotation.from_euler("z", a).as_matrix(), rng.normal(scale=0.1, size=3))
                       .compose(truth) for a in rng.normal(scale=0.05, size=30)]
    got = nearby_pairs_of(poses, observations, doubled, similarity, radius=0.5)
    assert sum(len(p) for p in got) > 60
    for pose, pairs in zip(poses, got):
        np.testing.assert_array_equal(pairs, dense_nearby_pairs(pose, observations, doubled, similarity, 0.5))


def test_hypotheses_with_the_same_nearby_pairs_are_refitted_alike():
    rng = np.random.default_rng(4)
    map, observations, truth = desk(rng)
    first = Hypothesis(Pose(truth.rotation, truth.translation + [0.02, 0, 0]), np.array([[0, 0], [1, 1], [2, 2]]), 3.0)
    second = Hypothesis(Pose(truth.rotation, truth.translation + [0, 0.02, 0]), np.array([[3, 3], [4, 4], [5, 5]]), 3.0)
    alone = Hypothesis(first.pose, first.correspondences, 3.0)
    refine([first, second], observations, map, np.eye(8), radius=0.3, weights="none")
    refine([alone], observations, map, np.eye(8), radius=0.3, weights="none")
    np.testing.assert_array_equal(first.correspondences, second.correspondences)
    assert (np.array_equal(first.pose.rotation, second.pose.rotation)
            and np.array_equal(first.pose.rotation, alone.pose.rotation))
    assert np.array_equal(first.pose.translation, alone.pose.translation) and len(first.correspondences) == 8


def test_pairs_are_taken_nearest_first_one_to_one():
    """Crowded landmarks, every pair within the radius: the greedy one-to-one choice, written out in Python."""
    rng = np.random.default_rng(3)
    landmarks, seen = rng.uniform(0, 0.5, (12, 3)), rng.uniform(0, 0.5, (9, 3))
    map = Map(Ellipsoids(landmarks, np.full((12, 3), 0.05), np.tile(np.eye(3), (12, 1, 1))), np.zeros(12, int), ["c"],
              [""] * 12, np.arange(12))
    observations = Observations(Ellipsoids(seen, np.full((9, 3), 0.05), np.tile(np.eye(3), (9, 1, 1))),
                                np.zeros(9, int), None, np.arange(9), np.arange(9))
    similarity = (rng.random((9, 12)) > 0.2).astype(float)
    distance = np.linalg.norm(seen[:, None] - landmarks[None], axis=-1)
    expected, used_obs, used_lm = [], set(), set()
    for flat in np.argsort(np.where(similarity > 0, distance, np.inf), axis=None, kind="stable"):
        k, n = divmod(int(flat), 12)
        if similarity[k, n] > 0 and k not in used_obs and n not in used_lm:
            used_obs.add(k), used_lm.add(n), expected.append((k, n))
    np.testing.assert_array_equal(nearby_pairs(Pose.identity(), observations, map, similarity, radius=1.0), expected)


def numpy_near_pairs(points, centers, similarity, radius, num_obs):
    """`refine._near_pairs` written with numpy: every pair's np.linalg.norm, the strict test, in row-major order."""
    distance = np.linalg.norm(points[:, None] - centers[None], axis=-1)
    point, landmark = np.nonzero((distance < radius) & (similarity[np.arange(len(points)) % num_obs] > 0))
    return distance[point, landmark], point // num_obs, point % num_obs, landmark


def test_the_kd_tree_join_s_near_pairs_hold_numpys_very_distances():
    rng = np.random.default_rng(5)
    for trial in range(100):
        num_obs, poses, count = int(rng.integers(1, 12)), int(rng.integers(1, 6)), int(rng.integers(1, 40))
        points = rng.normal(scale=0.6, size=(poses * num_obs, 3))
        centers = rng.normal(scale=0.6, size=(count, 3))
        if trial % 2:  # on a grid: pairs exactly at the radius, and ties
            points, centers = np.round(points * 4) / 4, np.round(centers * 4) / 4
        similarity = np.where(rng.random((num_obs, count)) < 0.8, rng.random((num_obs, count)), 0.0)
        radius = float(rng.choice([0.25, 0.5, 0.7]))
        got = refine_module._near_pairs(points, centers, similarity, radius, num_obs, None)
        distance, *indices = numpy_near_pairs(points, centers, similarity, radius, num_obs)
        np.testing.assert_allclose(got[0], distance, rtol=1e-15, atol=0)
        for ours, theirs in zip(got[1:], indices):
            np.testing.assert_array_equal(ours, theirs)


def test_the_compiled_order_and_choice_match_lexsort_and_a_greedy_loop():
    rng = np.random.default_rng(6)
    for trial in range(200):
        most = 30 if trial % 4 == 0 else 9  # a pose's hundreds of pairs, or a few
        num_poses, num_obs, num_landmarks = (int(rng.integers(1, 5)), int(rng.integers(1, most)),
                                             int(rng.integers(1, most)))
        candidates = np.array([(b, k, n) for b in range(num_poses) for k in range(num_obs) for n in range(num_landmarks)
                               if rng.random() < 0.6], np.int64).reshape(-1, 3)
        distance = rng.choice([0.1, 0.2, 0.3], size=len(candidates))  # many exact ties
        pose, obs, lm = candidates.T
        pairs, per_pose = refine_module._nearest_one_to_one(distance, pose, obs, lm, num_poses, num_obs, num_landmarks)
        expected, counts = [], np.zeros(num_poses, np.int64)
        for b in range(num_poses):
            used_obs, used_lm = set(), set()
            for i in np.lexsort((lm, obs, distance, pose)):
                if pose[i] == b and obs[i] not in used_obs and lm[i] not in used_lm:
                    used_obs.add(obs[i]), used_lm.add(lm[i]), expected.append((obs[i], lm[i]))
                    counts[b] += 1
        np.testing.assert_array_equal(pairs, np.array(expected, np.int64).reshape(-1, 2))
        np.testing.assert_array_equal(per_pose, counts)


def test_the_compiled_move_is_numpys_einsum():
    rng = np.random.default_rng(9)
    for poses, points in [(1, 1), (1, 7), (3, 1), (50, 15), (17, 40)]:
        rotations = np.array([Rotation.random(random_state=seed).as_matrix() for seed in range(poses)])
        translations, centers = rng.normal(scale=3.0, size=(poses, 3)), rng.normal(scale=2.0, size=(points, 3))
        expected = (np.einsum("bij,kj->bki", rotations, centers) + translations[:, None]).reshape(-1, 3)
        np.testing.assert_allclose(refine_module._apply_poses(rotations, translations, centers), expected, rtol=0,
                                   atol=1e-14)


def test_the_compiled_round_bookkeeping_is_numpys():
    """`_refitting`, `_chosen_pairs` and `_survivors` against the numpy expressions they replace: no pose, one, fifty;
    empty sets, sets under 3 and under the hypothesis's own size, ties of sizes, sets that found no pose."""
    rng = np.random.default_rng(12)
    for trial in range(300):
        poses = int(rng.choice([0, 1, 2, 7, 50]))
        counts, sizes = rng.integers(0, 9, poses), rng.integers(3, 7, poses)
        starts, refits = refine_module._refitting(counts, sizes)
        np.testing.assert_array_equal(starts, np.cumsum(counts) - counts)
        np.testing.assert_array_equal(refits, np.flatnonzero(counts >= np.maximum(3, sizes)))
        similarity = rng.choice([-0.0, 0.0, 0.4, np.nan, 0.9], size=(6, 9)).astype(rng.choice([np.float64, np.float32]))
        pairs = np.column_stack((rng.integers(0, 6, counts.sum()), rng.integers(0, 9, counts.sum())))
        chosen, scores = refine_module._chosen_pairs(pairs, starts[refits], counts[refits], similarity)
        expected = pairs[np.repeat(starts[refits] - np.cumsum(counts[refits]) + counts[refits], counts[refits])
                         + np.arange(counts[refits].sum())]
        np.testing.assert_array_equal(chosen, expected)
        assert scores.dtype == similarity.dtype
        np.testing.assert_array_equal(scores, similarity[expected[:, 0], expected[:, 1]])  # copies: NaN alike
        hypotheses = poses + int(rng.integers(0, 4))
        active = np.sort(rng.choice(hypotheses, poses, replace=False)).astype(np.int64)
        fitted = rng.integers(0, max(1, len(refits)), len(refits))
        rotation, translation = rng.normal(size=(max(1, len(refits)), 3, 3)), rng.normal(size=(max(1, len(refits)), 3))
        ok, offset = rng.random(max(1, len(refits))) < 0.7, int(rng.integers(0, 40))
        state = [rng.normal(size=(hypotheses, 3, 3)), rng.normal(size=(hypotheses, 3)), rng.integers(0, 9, hypotheses),
                 rng.integers(0, 99, hypotheses), rng.random(hypotheses) < 0.5]
        expected_state = [a.copy() for a in state]
        taken = refine_module._survivors(rotation, translation, ok, fitted, refits, active, starts, offset, counts,
                                         *state)
        kept = ok[fitted]
        kept_refits, kept_fitted = refits[kept], fitted[kept]
        expected_active = active[kept_refits]
        expected_state[0][expected_active] = rotation[kept_fitted]
        expected_state[1][expected_active] = translation[kept_fitted]
        expected_state[2][expected_active] = counts[kept_refits]
        expected_state[3][expected_active], expected_state[4][expected_active] = offset + starts[kept_refits], True
        np.testing.assert_array_equal(taken, expected_active)
        for got, want in zip(state, expected_state):
            np.testing.assert_array_equal(got, want)  # copied, not computed


def scattered_stack(rng, map, observations, truth, count):
    """`count` hypotheses around the true pose (a few centimetres to a metre off), each on 3 to 5 pairs."""
    rotations, translations, pairs, counts = [], [], [], []
    for _ in range(count):
        off = Pose(Rotation.from_euler("xyz", rng.normal(scale=0.08, size=3)).as_matrix(),
                   rng.normal(scale=rng.choice([0.02, 0.3]), size=3)).compose(truth)
        size = int(rng.integers(3, 6))
        rotations.append(off.rotation), translations.append(off.translation), counts.append(size)
        pairs.append(np.column_stack((rng.integers(0, len(observations), size), rng.integers(0, len(map), size))))
    return Stack(rotations=np.array(rotations).reshape(-1, 3, 3), translations=np.array(translations).reshape(-1, 3),
                 pairs=np.concatenate(pairs or [np.zeros((0, 2), np.int64)]), counts=np.array(counts, np.int64),
                 scores=rng.random(count), conditioning=rng.random(count))


def crowded_desk(rng, count):
    """`count` objects on a 1.2 m desk (a third of them twice: distance ties), seen with 1 cm noise."""
    centers = np.column_stack((rng.uniform(0, 1.2, count), rng.uniform(0, 0.6, count), rng.uniform(0.7, 0.9, count)))
    centers[: count // 3] = centers[count // 3: 2 * (count // 3)]
    axes = rng.uniform(0.02, 0.1, (count, 3))
    map = Map(Ellipsoids(centers, axes, np.tile(np.eye(3), (count, 1, 1))), np.arange(count), ["c"] * count,
              [""] * count, np.arange(count))
    truth = Pose(Rotation.from_euler("xyz", [-2.2, 0.1, 0.3]).as_matrix(), np.array([0.6, 1.5, 1.4]))
    seen = rng.choice(count, min(count, 14), replace=False)
    local = truth.inverse().apply(centers[seen]) + rng.normal(scale=0.01, size=(len(seen), 3))
    observed_axes = axes[seen] * rng.uniform(0.5, 1.2, (len(seen), 1))
    observations = Observations(Ellipsoids(local, observed_axes, np.tile(np.eye(3), (len(seen), 1, 1))),
                                np.zeros(len(seen), np.int64), None, seen, seen)
    return map, observations, truth


def same_refinement(got, want):
    """The same hypotheses moved onto the same pairs, their poses within 1e-9 (issue 34's tolerances)."""
    (stack, moved), (expected, expected_moved) = got, want
    np.testing.assert_array_equal(moved, expected_moved)
    for field in ("rotations", "translations", "pairs", "counts", "scores", "conditioning"):
        a, b = getattr(stack, field), getattr(expected, field)
        assert a.dtype == b.dtype and a.shape == b.shape, field
        if a.dtype.kind == "f":
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=field)
        else:
            np.testing.assert_array_equal(a, b, err_msg=field)


@pytest.mark.parametrize("weights", ["none", "sim", "com", "both"])
def test_the_one_compiled_refinement_is_the_round_by_round_one(weights, monkeypatch):
    """`_refine_densely` (through `refine_stack`) against `_refine_by_rounds`: no hypothesis, one, fifty; 0 to 3
    rounds; similarities with zeros, float32, NaN; an observation without a place; landmarks twice (ties)."""
    rng = np.random.default_rng(30)
    calls = []
    densely = refine_module._refine_densely
    monkeypatch.setattr(refine_module, "_refine_densely", lambda *a: calls.append(1) or densely(*a))
    refitted = 0
    for trial in range(60):
        map, observations, truth = crowded_desk(rng, int(rng.integers(3, 40)))
        stack = scattered_stack(rng, map, observations, truth, int(rng.choice([0, 1, 7, 50])))
        similarity = rng.random((len(observations), len(map))) * (rng.random((len(observations), len(map))) < 0.8)
        if trial % 4 == 1:
            similarity = similarity.astype(np.float32)
        if trial % 4 == 2:
            similarity[0, 0], similarity[-1] = np.nan, -0.0
        if trial % 5 == 3:
            observations.ellipsoids.centers[0] = np.nan
        rounds, radius = int(rng.integers(0, 4)), float(rng.choice([0.05, 0.15, 0.3]))
        with np.errstate(invalid="ignore"):
            got = refine_module.refine_stack(stack, observations, map, similarity, radius, weights, rounds)
            want = refine_module._refine_by_rounds(stack, observations, map, similarity, radius, weights, rounds,
                                                   None)
        same_refinement(got, want)
        assert got[1].any() or got[0] is stack
        refitted += got[1].any()
    assert len(calls) == 60 and refitted > 15


def test_sets_that_are_not_finite_are_not_refitted():
    """Moments that are not finite (a landmark's NaN axes in a weight, centres that overflow): those sets give no
    pose, so no hypothesis moves, in the compiled refinement and round by round alike; the stack is unchanged."""
    rng = np.random.default_rng(31)
    for spoiled in ("axes", "overflow"):
        map, observations, truth = crowded_desk(rng, 20)
        stack = scattered_stack(rng, map, observations, truth, 10)
        if spoiled == "axes":
            map.ellipsoids.axes[:] = np.nan
        else:
            map.ellipsoids.centers[:] = 1e160 * rng.random((20, 3))
            observations.ellipsoids.centers[:] = map.ellipsoids.centers[observations.instance_ids]
            stack = Stack(rotations=np.tile(np.eye(3), (10, 1, 1)), translations=np.zeros((10, 3)), pairs=stack.pairs,
                          counts=stack.counts, scores=stack.scores, conditioning=stack.conditioning)
        similarity = np.ones((len(observations), len(map)))
        before = [a.copy() for a in (stack.rotations, stack.translations, stack.counts, stack.pairs)]
        with np.errstate(all="ignore"):
            got = refine_module.refine_stack(stack, observations, map, similarity, 0.3, "both")
            same_refinement(got, refine_module._refine_by_rounds(stack, observations, map, similarity, 0.3, "both", 2,
                                                                 None))
        assert got[0] is stack and not got[1].any()
        for a, b in zip(before, (stack.rotations, stack.translations, stack.counts, stack.pairs)):
            np.testing.assert_array_equal(a, b)


def test_the_bisected_pairs_are_every_pair_tested():
    """`_nearest_of_all` meets only the centres within reach along the widest axis: against every pair tested
    (`dense_nearby_pairs`), pose after pose, with the map spread along x, y or z, on a grid (pairs exactly at the
    radius along that axis, ties), with NaN and inf centres and points, and landmarks far apart in magnitude."""
    rng = np.random.default_rng(32)
    found = 0
    for trial in range(120):
        count, seen = int(rng.integers(1, 50)), int(rng.integers(1, 12))
        centers = rng.uniform(0, 1.5, (count, 3)) * np.roll([4.0, 1.0, 0.3], trial % 3)
        if trial % 2:
            centers = np.round(centers * 4) / 4
        if trial % 7 == 0:
            centers[0, trial % 3], centers[-1] = np.inf, (-np.inf, 0.5, np.nan)
        if trial % 11 == 0:
            centers[: count // 2] *= 1e12
        map = Map(Ellipsoids(centers, np.full((count, 3), 0.05), np.tile(np.eye(3), (count, 1, 1))),
                  np.zeros(count, np.int64), ["c"], [""] * count, np.arange(count))
        local = centers[rng.integers(0, count, seen)] + rng.choice([0.0, 0.25, -0.5], size=(seen, 3))
        if trial % 5 == 0:
            local[0, trial % 3], local[-1] = np.nan, (np.inf, -np.inf, 0.0)
        observations = Observations(Ellipsoids(local, np.full((seen, 3), 0.05), np.tile(np.eye(3), (seen, 1, 1))),
                                    np.zeros(seen, np.int64), None, np.arange(seen), np.arange(seen))
        similarity = np.where(rng.random((seen, count)) < 0.8, rng.random((seen, count)), 0.0)
        poses = [Pose.identity()] + [Pose(Rotation.random(random_state=seed).as_matrix(), rng.normal(size=3) * 0.1)
                                     for seed in range(int(rng.integers(0, 4)))]
        radius = float(rng.choice([0.25, 0.5, 0.3]))
        with np.errstate(invalid="ignore"):
            got = nearby_pairs_of(poses, observations, map, similarity, radius)
            for pose, pairs in zip(poses, got):
                np.testing.assert_array_equal(pairs, dense_nearby_pairs(pose, observations, map, similarity, radius))
                found += len(pairs)
    assert found > 150


def test_the_centres_are_ordered_along_their_widest_finite_spread_without_nan():
    centers = np.array([[0.0, 5.0, 1.0], [0.2, -1.0, np.inf], [np.nan, 2.0, 0.5], [0.1, np.nan, 0.0], [0.3, 0.0, 4.0]])
    by_axis, axis, landmark_of = refine_module._along_widest_axis(centers)
    assert axis == 1 and landmark_of.tolist() == [1, 4, 2, 0]  # z's inf is no spread; landmark 3 has no y
    assert by_axis.flags.c_contiguous
    np.testing.assert_array_equal(by_axis, centers[landmark_of].T)
    assert refine_module._along_widest_axis(np.zeros((0, 3)))[0].shape == (3, 0)


def test_each_hypothesis_refines_as_it_would_alone():
    """A hypothesis's refinement is its own, whatever the others refitted beside it: the stack refined at once (the
    compiled pass, which also gives a set fitted in an earlier round its earlier fit) and round by round, against
    each hypothesis refined alone, to the bit; with the first observation's and the first landmark's centres NaN
    (a batch's padding once made every padded set of it degenerate)."""
    rng = np.random.default_rng(32)
    moved = 0
    for trial in range(40):
        map, observations, truth = crowded_desk(rng, int(rng.integers(6, 40)))
        stack = scattered_stack(rng, map, observations, truth, int(rng.choice([2, 7, 30])))
        similarity = rng.random((len(observations), len(map))) * (rng.random((len(observations), len(map))) < 0.8)
        if trial % 2:
            observations.ellipsoids.centers[0] = np.nan
            map.ellipsoids.centers[0] = np.nan
        rounds = int(rng.integers(1, 4))
        with np.errstate(invalid="ignore"):
            together = refine_module.refine_stack(stack, observations, map, similarity, 0.3, "both", rounds)
            by_rounds = refine_module._refine_by_rounds(stack, observations, map, similarity, 0.3, "both", rounds,
                                                        None)
            alone = [refine_module.refine_stack(stack.take(np.array([b])), observations, map, similarity, 0.3, "both",
                                                rounds) for b in range(len(stack))]
        for b, (single, single_moved) in enumerate(alone):
            row = together[0].take(np.array([b]))
            for field in ("rotations", "translations", "pairs", "counts"):
                np.testing.assert_array_equal(getattr(row, field), getattr(single, field), err_msg=field)
            assert together[1][b] == single_moved[0]
        same_refinement(by_rounds, together)
        moved += together[1].sum()
    assert moved > 200


def test_the_known_sets_are_a_dictionary_of_their_pairs():
    """`_known_sets` against a dictionary keyed by each set's pairs in order: sets known from earlier rounds, repeated
    in this one, in another order (not alike), one a prefix of another, none known."""
    rng = np.random.default_rng(33)
    reused = 0
    for trial in range(300):
        pool = [rng.integers(0, 4, (int(rng.integers(3, 6)), 2)) for _ in range(int(rng.integers(1, 8)))]
        pool += [pool[0][::-1], pool[0][:-1]] if len(pool[0]) > 3 else []
        known = [pool[i] for i in rng.choice(len(pool), int(rng.integers(0, len(pool) + 1)), replace=False)]
        known = list({pairs.tobytes(): pairs for pairs in known}.values())  # the known sets are distinct
        asked = [pool[i] for i in rng.integers(0, len(pool), int(rng.integers(0, 12)))]
        found = np.concatenate(known + asked + [np.zeros((0, 2), np.int64)]).astype(np.int64)
        set_counts = np.array([len(s) for s in known], np.int64)
        counts = np.array([len(s) for s in asked], np.int64)
        starts = set_counts.sum() + np.cumsum(counts) - counts
        fitted, fresh = refine_module._known_sets(found, starts, counts, np.cumsum(set_counts) - set_counts,
                                                  set_counts, len(known))
        numbers = {s.tobytes(): i for i, s in enumerate(known)}
        expected, firsts = [], []
        for r, s in enumerate(asked):
            if s.tobytes() not in numbers:
                numbers[s.tobytes()] = len(numbers)
                firsts.append(r)
            expected.append(numbers[s.tobytes()])
        assert fitted.tolist() == expected and fresh.tolist() == firsts
        reused += sum(number < len(known) for number in expected)
    assert reused > 200
