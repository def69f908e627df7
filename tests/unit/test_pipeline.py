import dataclasses

import numpy as np
import pytest

from clipclique.config import ConfigError, make_config
from clipclique.errors import ClipcliqueError
from clipclique.metrics import evaluate_frame, summarize
from clipclique.outcomes import PIPELINE_STAGES, Failure, FailureKind
from clipclique.pipeline import RANK_DECIMALS, _objects, _stacked, _valid, _without_added, index_map, localize
from clipclique.pose.distance import pose_errors
from clipclique.sim.synthetic import synthetic_map, synthetic_query
from clipclique.types import Ellipsoids, Observations


def run(method: str, frames: int = 12, overrides: list[str] | None = None, seed: int = 1, **query):
    config = make_config(method, overrides=overrides)
    rng = np.random.default_rng(seed)
    map = synthetic_map(rng, num_landmarks=40, num_classes=8)
    index = index_map(map, config)
    evaluations, results = [], []
    for frame in range(frames):
        observations, truth = synthetic_query(map, rng, **query)
        result = localize(observations, index, config)
        results.append(result)
        evaluations.append(evaluate_frame(result, observations, map, truth, config, frame))
    return summarize(evaluations), results


# The baselines need no CLIP (SH, X-View) or no graph (CLIP-Loc); all localize this easy synthetic map.
# 24 frames: RANSAC verified by projected overlap (the paper's) misses a frame or two more than by centres.
@pytest.mark.parametrize(
    ("method", "success", "precision"), [("clipclique", 1.0, 0.95), ("sh", 0.75, 0.95), ("xview", 0.75, 0.95),
                                         ("cliploc", 0.9, 0.95)]
)
def test_each_method_localizes_synthetic_frames(method, success, precision):
    summary, results = run(method, frames=24)
    assert summary["success@1"] >= success
    assert summary["precision"] >= precision
    assert summary["te_median_m"] < 0.2 and summary["re_median_deg"] < 5.0
    for result in results:
        assert set(result.timings) >= set(PIPELINE_STAGES)
        assert len(result.hypotheses) <= 5
        # CLIP-Clique re-ranks by image verification by default; the baselines keep their score's order
        # (keys equal to RANK_DECIMALS tie and keep the pool's order)
        keys = [round(h.verification, RANK_DECIMALS) if method == "clipclique" else h.score for h in result.hypotheses]
        assert keys == sorted(keys, reverse=True)


def test_clipclique_beats_sh_on_small_noisy_views():
    # 6 objects and 3 false detections: histograms of a small view are unreliable, CLIP still tells objects apart
    clipclique, _ = run("clipclique", num_visible=6, num_outliers=3)
    sh, _ = run("sh", num_visible=6, num_outliers=3)
    assert clipclique["success@1"] > sh["success@1"]
    assert clipclique["recall"] > sh["recall"]


def test_hypotheses_are_one_to_one_and_consistent_with_their_pose():
    _, results = run("clipclique", frames=3)
    for result in results:
        for hypothesis in result.hypotheses:
            pairs = hypothesis.correspondences
            assert len(pairs) >= 3
            assert len(np.unique(pairs[:, 0])) == len(pairs) == len(np.unique(pairs[:, 1]))


def test_fewer_than_three_observations_is_a_documented_failure():
    config = make_config("clipclique")
    map = synthetic_map(np.random.default_rng(0))
    observations, _ = synthetic_query(map, np.random.default_rng(0), num_visible=2, num_outliers=0)
    result = localize(observations, index_map(map, config), config)
    assert result.hypotheses == [] and result.failure == Failure(kind=FailureKind.FEW_OBSERVATIONS, count=2)
    assert result.failure.message == "fewer than 3 observations (2)"
    assert result.similarity.shape == (2, len(map))


def test_no_candidates_is_a_documented_failure():
    config = make_config("clipclique", overrides=["matching.min_similarity=0.99"])
    map = synthetic_map(np.random.default_rng(0))
    observations, _ = synthetic_query(map, np.random.default_rng(0))
    result = localize(observations, index_map(map, config), config)
    assert result.failure.kind is FailureKind.FEW_MATCHED


def test_missing_embeddings_fall_back_to_sh_for_fused_and_fail_for_clip():
    map = synthetic_map(np.random.default_rng(0))
    observations, truth = synthetic_query(map, np.random.default_rng(0))
    blind = dataclasses.replace(map, text_embeddings=None)
    config = make_config("clipclique")
    result = localize(observations, index_map(blind, config), config)
    assert result.notes == ["no CLIP embeddings (the map has no text embeddings): alpha = 0 (SH only)"]
    sh = make_config("clipclique", overrides=["similarity.descriptor=sh"])
    np.testing.assert_allclose(result.similarity, localize(observations, index_map(blind, sh), sh).similarity)
    with pytest.raises(ClipcliqueError, match="needs CLIP embeddings"):
        cliploc = make_config("cliploc")
        localize(observations, index_map(blind, cliploc), cliploc)


def test_bad_observation_classes_and_embedding_sizes_are_user_errors():
    map = synthetic_map(np.random.default_rng(0), num_classes=8)
    observations, _ = synthetic_query(map, np.random.default_rng(0))
    config = make_config("clipclique")
    index = index_map(map, config)
    with pytest.raises(ClipcliqueError, match="8 classes"):
        localize(dataclasses.replace(observations, class_ids=observations.class_ids + 8), index, config)
    with pytest.raises(ClipcliqueError, match="dimensions"):
        localize(dataclasses.replace(observations, image_embeddings=observations.image_embeddings[:, :5]), index,
                 config)
    for part, row in (("centers", 2), ("axes", 0), ("rotations", 1)):  # one bad row failed the whole frame silently
        shapes = dataclasses.replace(observations.ellipsoids, **{part: getattr(observations.ellipsoids, part).copy()})
        getattr(shapes, part)[row] = np.nan if part != "axes" else np.inf
        with pytest.raises(ClipcliqueError,
                           match=rf"observation {row} has a centre, axes or rotation that is not finite "
                                                  rf"\(1 of {len(observations)} observations\)"):
            localize(dataclasses.replace(observations, ellipsoids=shapes), index, config)


def test_the_compiled_observation_check_is_the_numpy_one():
    """`_valid` (the check's fast path) against the numpy tests it replaced: ids below 0 or past the classes, NaN and
    infinities in any part, huge finite values, no observations, and a strided (non-contiguous) part."""
    rng = np.random.default_rng(4)
    special = np.array([np.nan, np.inf, -np.inf, 1e308, -0.0])
    for trial in range(300):
        k, classes = int(rng.integers(0, 6)), int(rng.integers(1, 9))
        ids = rng.integers(-1 if trial % 3 == 0 else 0, classes + (trial % 5 == 0), k)
        parts = [rng.random((k, 3)), rng.random((k, 3)), rng.random((k, 3, 3))]
        if k and trial % 2:
            part = parts[trial % 3]
            part.reshape(-1)[rng.integers(0, part.size)] = rng.choice(special)
        if trial % 7 == 0:
            parts[0] = np.asfortranarray(parts[0])
        expected = ((not len(ids) or (ids.min() >= 0 and ids.max() < classes))
                    and all(np.isfinite(part).all() for part in parts))
        assert _valid(ids, classes, *parts) == expected


def test_the_pipeline_is_deterministic():
    first, _ = run("cliploc", frames=3)
    second, _ = run("cliploc", frames=3)
    assert {k: v for k, v in first.items() if not k.startswith("time")} == {
        k: v for k, v in second.items() if not k.startswith("time")
    }


@pytest.mark.parametrize("weights", ["none", "sim", "com", "both"])
def test_pose_weight_ablations_run_through_one_pipeline(weights):
    summary, results = run("clipclique", frames=4, overrides=[f"pose.weights={weights}"])
    assert summary["success@1"] == 1.0
    truth_free = [h.pose for r in results for h in r.hypotheses]
    assert all(np.isfinite(p.matrix()).all() for p in truth_free)


def test_top1_pose_error_is_the_metric_error():
    config = make_config("clipclique")
    map = synthetic_map(np.random.default_rng(2))
    observations, truth = synthetic_query(map, np.random.default_rng(2))
    result = localize(observations, index_map(map, config), config)
    evaluation = evaluate_frame(result, observations, map, truth, config, 0)
    assert (evaluation.translation_error, evaluation.rotation_error) == pose_errors(result.hypotheses[0].pose, truth)


def test_an_index_built_for_another_config_is_refused():
    map = synthetic_map(np.random.default_rng(0))
    observations, _ = synthetic_query(map, np.random.default_rng(0))
    index = index_map(map, make_config("sh"))
    with pytest.raises(ClipcliqueError, match="index_map"):
        localize(observations, index, make_config("sh", overrides=["graph.d_adj=1.0"]))
    with pytest.raises(ClipcliqueError, match="index_map"):
        localize(observations, index, make_config("xview"))


@pytest.mark.parametrize("method", ["clipclique", "sh", "xview", "cliploc"])
def test_empty_map_or_frame_fails_cleanly(method):
    config = make_config(method)
    map = synthetic_map(np.random.default_rng(0))
    observations, _ = synthetic_query(map, np.random.default_rng(0))
    nothing = np.arange(0)
    empty_map = dataclasses.replace(
        map, ellipsoids=map.ellipsoids.subset(nothing), class_ids=map.class_ids[nothing], descriptions=[],
        instance_ids=map.instance_ids[nothing], text_embeddings=map.text_embeddings[nothing],
    )
    result = localize(observations, index_map(empty_map, config), config)
    assert result.similarity.shape == (len(observations), 0) and result.hypotheses == []
    assert result.failure.message == "fewer than 3 observations with a candidate landmark (0)"
    empty_frame = dataclasses.replace(
        observations, ellipsoids=observations.ellipsoids.subset(nothing), class_ids=observations.class_ids[nothing],
        image_embeddings=observations.image_embeddings[nothing], instance_ids=observations.instance_ids[nothing],
        detection_index=nothing,
    )
    result = localize(empty_frame, index_map(map, config), config)
    assert (result.similarity.shape == (0, len(map))
            and result.failure == Failure(kind=FailureKind.FEW_OBSERVATIONS, count=0))


@pytest.mark.parametrize(
    "override",
    ["graph.xview_walks=-1", "inliers.max_cliques=0", "inliers.ransac_iterations=0", "top_n=0",
     "success_threshold_m=0"],
)
def test_counts_and_thresholds_out_of_range_are_config_errors(override):
    # xview_walks=-1 crashed numpy; max_cliques <= 0 reported a cap hit with no clique looked at
    with pytest.raises(ConfigError, match=override.split("=")[0]):
        make_config("xview", overrides=[override])


def test_an_object_detected_twice_with_two_classes_never_enters_one_clique_twice():
    from clipclique.types import Camera, Ellipsoids, Map, Observations
    from clipclique.types import Pose as TruePose

    # a cup and a bottle 3 cm apart on a desk, three other objects; the camera sees the cup twice
    # (once as "cup", once as "bottle": one box, two classes) and the three others
    centers = np.array([[0.0, 0, 0], [0.03, 0, 0], [0.6, 0.1, 0], [0.1, 0.7, 0], [-0.5, 0.3, 0.2]])
    axes = np.full((5, 3), 0.05)
    rotations = np.tile(np.eye(3), (5, 1, 1))
    map = Map(Ellipsoids(centers, axes, rotations), np.array([0, 1, 2, 3, 4]), ["cup", "bottle", "book", "mouse", "tv"],
              [""] * 5, np.arange(5))
    truth = TruePose(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 1.5]))  # looking down from 1.5 m
    seen = truth.inverse().apply(centers[[0, 0, 2, 3, 4]])
    camera = Camera(np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), 640, 480)
    boxes = np.array([[300, 220, 340, 260], [301, 221, 340, 260], [100, 100, 150, 150], [400, 300, 450, 350],
                      [500, 50, 560, 110]], float)
    observations = Observations(Ellipsoids(seen, axes.copy(), rotations.copy()), np.array([0, 1, 2, 3, 4]), None,
                                np.array([0, 0, 2, 3, 4]), np.arange(5), boxes, None, camera)

    def uses_both(overrides):
        config = make_config("clipclique", overrides=["similarity.alpha=0"] + overrides)
        best = localize(observations, index_map(map, config), config).hypotheses[0]
        return {0, 1} <= set(best.correspondences[:, 0].tolist())

    assert uses_both(["inliers.duplicate_iou=0.0", "pose.refine_radius=0.0"])  # five "objects" outweigh four
    assert not uses_both(["inliers.duplicate_iou=0.7", "pose.refine_radius=0.0"])


def test_an_observation_overlapping_an_earlier_one_shows_that_ones_object():
    """A chain of overlaps joins one object; a box overlapping nothing earlier keeps its own."""
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [2, 0, 12, 10], [50, 50, 60, 60], [51, 50, 61, 60]], float)
    observations = Observations(Ellipsoids(np.zeros((5, 3)), np.ones((5, 3)), np.tile(np.eye(3), (5, 1, 1))),
                                np.zeros(5, int), None, np.arange(5), np.arange(5), boxes=boxes)
    assert _objects(observations, 0.8).tolist() == [0, 0, 0, 3, 3]  # box 2 overlaps box 0 at 0.67, box 1 at 0.82
    assert _objects(observations, 0.85).tolist() == [0, 1, 2, 3, 4]
    assert _objects(observations, 0.0).tolist() == [0, 1, 2, 3, 4]  # 0: off


def test_cliques_holding_added_lookalike_pairs_are_also_tried_without_them():
    added = np.array([False, False, False, True, True, False])
    cliques = [np.array([0, 1, 2, 3]),  # without 3: {0, 1, 2}
               np.array([3, 4, 0, 1]),  # without 3 and 4: {0, 1}, too few
               np.array([2, 1, 0, 4]),  # without 4: {0, 1, 2} again
               np.array([5, 1, 2]),  # nothing added: as it is
               np.array([5, 1, 2, 4])]  # without 4: {1, 2, 5}, a clique already
    assert [members.tolist() for members in without_added(cliques, added, 3)] == [[0, 1, 2]]
    assert without_added(cliques, added, 2)[1].tolist() == [0, 1]


def without_added(cliques, added, min_size):
    """`_without_added` of a list of cliques, as a list."""
    members, sizes, _ = _without_added(*_stacked(cliques), added, np.zeros(len(added)), min_size)
    return np.split(members, np.cumsum(sizes)[:-1]) if len(sizes) else []


def without_added_loop(cliques, added, min_size):
    """`_without_added` written as a loop over the cliques with sorted tuples as keys."""
    known = {tuple(sorted(members.tolist())) for members in cliques}
    out = []
    for members in cliques:
        rest = members[~added[members]]
        key = tuple(sorted(rest.tolist()))
        if min_size <= len(rest) < len(members) and key not in known:
            known.add(key)
            out.append(rest)
    return out


def test_cliques_without_added_pairs_are_the_loop_s_in_its_order():
    rng, found = np.random.default_rng(12), 0
    for trial in range(300):
        count = int(rng.integers(1, 12))
        added = rng.random(count) < rng.choice([0.0, 0.2, 0.5])
        cliques = [rng.permutation(count)[: int(rng.integers(1, count + 1))] for _ in range(int(rng.integers(0, 15)))]
        cliques += [rng.permutation(members) for members in cliques[:2]]  # a clique twice, in another order
        min_size = int(rng.integers(1, 4))
        got, expected = without_added(cliques, added, min_size), without_added_loop(cliques, added, min_size)
        assert [m.tolist() for m in got] == [m.tolist() for m in expected]
        found += len(expected)
    assert found > 100


def numpy_without_added(members, sizes, added, scores, min_size):
    """`_without_added` as its numpy passes computed it before it was compiled, the totals numpy's sums of the
    gathered scores."""
    from clipclique.pose.stack import alike

    owner = np.repeat(np.arange(len(sizes)), sizes)
    ordered = members[np.lexsort((members, owner))]
    left = ~added[ordered]
    rest_sizes = np.bincount(owner[left], minlength=len(sizes))
    eligible = (rest_sizes >= min_size) & (rest_sizes < sizes)
    counts = np.concatenate((sizes, rest_sizes[eligible]))
    group, firsts = alike(np.zeros((len(counts), 0)), np.concatenate((ordered, ordered[left & eligible[owner]])),
                          np.cumsum(counts) - counts, counts)
    kept = np.zeros(len(sizes), bool)
    kept[eligible] = firsts[group[len(sizes):]] == np.arange(len(sizes), len(counts))
    rests = np.repeat(kept, sizes) & ~added[members]
    rest_sizes = np.bincount(owner[rests], minlength=len(sizes))[kept]
    gathered = np.split(scores[members[rests]], np.cumsum(rest_sizes)[:-1]) if len(rest_sizes) else []
    return members[rests], rest_sizes, np.array([group.sum() for group in gathered], np.float64)


def test_the_compiled_rests_are_the_numpy_passes():
    """`_without_added` against its numpy passes, arrays and dtypes: random cliques with repeats in other orders,
    nothing or everything added, single and no cliques; scores with ties, -0, NaN and inf, rests of 8 or more."""
    rng = np.random.default_rng(13)
    cases = [([], np.zeros(4, bool)), ([np.array([3, 1, 2])], np.ones(4, bool)),
             ([np.array([3, 1, 2])], np.zeros(4, bool)), ([np.array([0, 1, 2, 3]), np.array([3, 2, 1, 0])],
                                                          np.array([True, False, False, False]))]
    for trial in range(300):
        count = int(rng.integers(1, 24))
        cliques = [rng.permutation(count)[: int(rng.integers(1, count + 1))] for _ in range(int(rng.integers(0, 12)))]
        cliques += [rng.permutation(members) for members in cliques[:3]]
        cases.append((cliques, rng.random(count) < rng.choice([0.0, 0.2, 0.5, 1.0])))
    kept = 0
    for trial, (cliques, added) in enumerate(cases):
        scores = rng.random(len(added)) if trial % 2 else np.round(rng.normal(size=len(added)), 1)  # ties
        if trial % 7 == 0:
            scores[rng.integers(len(added))] = rng.choice([-0.0, np.nan, np.inf, -np.inf])
        for min_size in (1, 2, 3):
            got = _without_added(*_stacked(cliques), added, scores, min_size)
            expected = numpy_without_added(*_stacked(cliques), added, scores, min_size)
            for ours, theirs in zip(got, expected):
                assert ours.dtype == theirs.dtype
            np.testing.assert_array_equal(got[0], expected[0])
            np.testing.assert_array_equal(got[1], expected[1])
            np.testing.assert_allclose(got[2], expected[2], rtol=1e-12, atol=1e-12)
            kept += len(expected[1])
    assert kept > 200


def test_usable_fits_are_the_numpy_mask():
    """`pipeline._usable` against the numpy expression it replaced, `ok & (nonzero_counts(weights) >= 3) &
    (measure >= floor)` and its `.all()`: weights of 0, -0 and NaN (a NaN counts), NaN and infinite measures, a
    measure exactly at the floor, sets already not ok, and an empty batch."""
    from clipclique.pipeline import _usable
    from clipclique.pose.fit import nonzero_counts

    rng = np.random.default_rng(31)
    for trial in range(500):
        count, width = int(rng.integers(0, 6)), int(rng.integers(0, 6))
        weights = rng.choice([0.0, -0.0, np.nan, 0.5, 1.0], size=(count, width))
        measure = rng.choice([0.0, 0.01, 0.2, np.nan, np.inf, -np.inf], size=count)
        ok = rng.random(count) < 0.8
        floor = float(rng.choice([0.0, 0.01, 0.2, -np.inf]))
        expected = ok & (nonzero_counts(weights) >= 3) & (measure >= floor)
        got = ok.copy()
        assert _usable(got, weights, measure, floor) == expected.all()
        np.testing.assert_array_equal(got, expected)


def test_the_fitted_stack_is_the_masked_rows():
    """`_hypotheses` hands the fits' arrays on as they are when every set gives a pose, and drops the others when
    not: both against the plain masked construction (a collinear set and one of two positive weights
    among good ones; all good)."""
    from clipclique.pipeline import LocalizationResult, _hypotheses
    from clipclique.pose.fit import fit_rigid_conditioned, nonzero_counts, weighted_sets

    config = make_config("clipclique")
    rng = np.random.default_rng(3)
    map = synthetic_map(rng, num_landmarks=40, num_classes=8)
    observations, _ = synthetic_query(map, rng)
    count = len(observations)
    candidates = np.column_stack((np.arange(count), rng.integers(0, len(map), count))).astype(np.int64)
    scores = rng.uniform(0.2, 1.0, count)
    scores[4] = 0.0  # a zero weight: the set (3, 4, 5) has two positive weights
    observations.ellipsoids.centers[[0, 1, 2]] = np.outer([0.0, 1.0, 2.0], [1.0, 0.5, 0.25])  # collinear: (0, 1, 2)
    result = LocalizationResult(hypotheses=[], candidates=candidates, candidate_scores=scores, similarity=np.zeros(0),
                                num_cliques=0, cap_hit=None, failure=None)
    good = [np.array([5, 6, 7, 8]), np.array([6, 7, 9]), np.array([1, 5, 8, 9])]
    for sets in (good, [np.array([0, 1, 2]), *good, np.array([3, 4, 5])]):
        members, sizes = _stacked(sets)
        totals = rng.random(len(sets))
        got = _hypotheses(result, observations, map, config, members, sizes, totals)
        pairs, first = candidates[members], candidates[0]
        source, target, weights = weighted_sets(
            pairs, scores[members], sizes, (first[0], first[1], scores[0]),
            (observations.ellipsoids.centers, observations.ellipsoids.axes),
            (map.ellipsoids.centers, map.ellipsoids.axes),
            config.pose.weights)
        rotation, translation, ok, measure = fit_rigid_conditioned(source, target, weights)
        ok &= (nonzero_counts(weights) >= 3) & (measure >= config.pose.min_conditioning)
        assert ok.sum() == (len(sets) if sets is good else len(good))
        expected = (rotation[ok], translation[ok], pairs[np.repeat(ok, sizes)], sizes[ok], totals[ok], measure[ok])
        for ours, theirs in zip((got.rotations, got.translations, got.pairs, got.counts, got.scores, got.conditioning),
                                expected):
            assert ours.dtype == theirs.dtype and ours.shape == theirs.shape
            if ours.dtype.kind == "f":
                np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)
            else:
                np.testing.assert_array_equal(ours, theirs)
