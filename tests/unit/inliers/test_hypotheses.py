"""What the inlier stage hands on (clipclique.inliers.hypotheses): the clique search's sets fitted as a Stack,
degenerate cliques skipped, cliques tried without their added look-alike pairs, one object detected twice."""

import numpy as np

from clipclique.config import make_config
from clipclique.inliers.hypotheses import (
    _flatten_sets,
    _holds_rest,
    _hypotheses,
    _objects,
    _without_added,
    from_cliques,
)
from clipclique.outcomes import LocalizationResult
from clipclique.sim.synthetic import synthetic_map, synthetic_query
from clipclique.types import Ellipsoids, Map, Observations


def test_a_degenerate_best_clique_is_skipped_and_the_search_goes_on():
    """The heaviest clique is collinear (no pose); top_n = 1 must still give the next one."""
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    triangle = np.array([[10, 0, 0], [10, 1, 0], [11, 0, 0.0]])
    observed = np.concatenate((line, triangle))
    landmarks = np.concatenate((line, triangle + [0, 5, 0]))  # the two groups disagree across
    ellipsoids = lambda c: Ellipsoids(c, np.full((6, 3), 0.2), np.repeat(np.eye(3)[None], 6, 0))  # noqa: E731
    map = Map(ellipsoids(landmarks), np.zeros(6, int), ["thing"], ["thing"] * 6, np.arange(6) + 1, None, "none", {})
    observations = Observations(ellipsoids(observed), np.zeros(6, int), None, np.arange(6) + 1, np.arange(6))
    candidates = np.column_stack((np.arange(6), np.arange(6)))
    scores = np.array([0.9, 0.9, 0.9, 0.5, 0.5, 0.5])
    config = make_config("clipclique", overrides={"top_n": 1})
    result = LocalizationResult(hypotheses=[], candidates=candidates, candidate_scores=scores, similarity=np.eye(6),
                                num_cliques=0, cap_hit=None, failure=None)
    hypotheses = from_cliques(result, observations, map, config, lambda stage: None).hypotheses()
    assert len(hypotheses) == 1 and result.failure is None
    assert hypotheses[0].correspondences[:, 0].tolist() == [3, 4, 5]
    np.testing.assert_allclose(hypotheses[0].pose.translation, [0, 5, 0], atol=1e-9)


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
    members, sizes, _ = _without_added(*_flatten_sets(cliques), added, np.zeros(len(added)), min_size)
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
    nothing or everything added, single and no cliques; scores with ties, -0, NaN and inf, rests of 8 or more. And
    `_holds_rest` against numpy's count of each clique's rest: where it says none, `_without_added` gives none."""
    rng = np.random.default_rng(13)
    cases = [([], np.zeros(4, bool)), ([np.array([3, 1, 2])], np.ones(4, bool)),
             ([np.array([3, 1, 2])], np.zeros(4, bool)), ([np.array([0, 1, 2, 3]), np.array([3, 2, 1, 0])],
                                                          np.array([True, False, False, False]))]
    for trial in range(300):
        count = int(rng.integers(1, 24))
        cliques = [rng.permutation(count)[: int(rng.integers(1, count + 1))] for _ in range(int(rng.integers(0, 12)))]
        cliques += [rng.permutation(members) for members in cliques[:3]]
        cases.append((cliques, rng.random(count) < rng.choice([0.0, 0.2, 0.5, 1.0])))
    kept = skipped = 0
    for trial, (cliques, added) in enumerate(cases):
        scores = rng.random(len(added)) if trial % 2 else np.round(rng.normal(size=len(added)), 1)  # ties
        if trial % 7 == 0:
            scores[rng.integers(len(added))] = rng.choice([-0.0, np.nan, np.inf, -np.inf])
        for min_size in (1, 2, 3):
            got = _without_added(*_flatten_sets(cliques), added, scores, min_size)
            expected = numpy_without_added(*_flatten_sets(cliques), added, scores, min_size)
            for ours, theirs in zip(got, expected):
                assert ours.dtype == theirs.dtype
            np.testing.assert_array_equal(got[0], expected[0])
            np.testing.assert_array_equal(got[1], expected[1])
            np.testing.assert_allclose(got[2], expected[2], rtol=1e-12, atol=1e-12)
            kept += len(expected[1])
            members, sizes = _flatten_sets(cliques)
            rests = np.add.reduceat(~added[members], np.cumsum(sizes) - sizes) if len(members) else np.zeros(0)
            holds = bool(((rests >= min_size) & (rests < sizes)).any()) if len(sizes) and len(members) else False
            assert _holds_rest(members, sizes, added, min_size) is holds
            assert holds or not len(got[1])  # no clique with a rest: nothing to give
            skipped += not holds
    assert kept > 200 and skipped > 100


def test_the_fitted_stack_is_the_masked_rows():
    """`_hypotheses` hands the fits' arrays on as they are when every set gives a pose, and drops the others when
    not: both against the plain masked construction (a collinear set and one of two positive weights
    among good ones; all good)."""
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
        members, sizes = _flatten_sets(sets)
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
