import itertools

import networkx as nx
import numpy as np
import pytest

from clipclique.inliers.compatibility import affordable_candidates, compatibility_graph
from clipclique.inliers.consensus import sample_consensus
from clipclique.inliers.reference_cliques import maximal_cliques, rank_cliques
from clipclique.pose.distance import pose_errors
from clipclique.pose.fit import fit_rigid
from clipclique.sim.poses import random_rotation
from clipclique.types import Pose


def outlier_heavy_problem(seed: int, inliers: int = 8, wrong_per_observation: int = 5):
    """Landmarks, camera-frame observations of `inliers` of them, and candidates of which more than 80% are wrong."""
    rng = np.random.default_rng(seed)
    landmarks = rng.uniform(0, 6, size=(50, 3))
    truth = Pose(random_rotation(rng), rng.uniform(-3, 3, 3))
    seen = rng.choice(50, inliers, replace=False)
    observed = truth.inverse().apply(landmarks[seen]) + rng.normal(scale=0.02, size=(inliers, 3))
    right = np.column_stack((np.arange(inliers), seen))
    wrong = np.column_stack(
        (np.repeat(np.arange(inliers), wrong_per_observation), rng.integers(0, 50, inliers * wrong_per_observation))
    )
    wrong = wrong[wrong[:, 1] != np.repeat(seen, wrong_per_observation)]
    candidates = np.concatenate((right, wrong))
    assert len(wrong) / len(candidates) >= 0.8
    return landmarks, observed, candidates, truth, len(right)


def test_compatibility_graph_applies_the_rigid_distance_test():
    observed = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0.0]])
    landmarks = np.array([[5, 5, 0], [6.2, 5, 0], [5, 7, 0], [9, 9, 9.0]])
    candidates = np.array([[0, 0], [1, 1], [2, 2], [2, 3], [0, 3]])
    edges = compatibility_graph(observed, landmarks, candidates, d_comp=0.3)
    # |1 - 1.2| < 0.3; candidate 3 is far; 0-4 and 3-4 share an observation or landmark
    expected = {(0, 1), (0, 2), (1, 2)}
    assert set(map(tuple, edges.tolist())) == expected
    assert (0, 1) not in set(map(tuple, compatibility_graph(observed, landmarks, candidates, d_comp=0.1).tolist()))


def test_compatibility_graph_equals_the_all_pairs_test():
    landmarks, observed, candidates, _, _ = outlier_heavy_problem(4)
    obs, lm = candidates[:, 0], candidates[:, 1]
    observed_distance = np.linalg.norm(observed[obs][:, None] - observed[obs][None], axis=-1)
    mapped_distance = np.linalg.norm(landmarks[lm][:, None] - landmarks[lm][None], axis=-1)
    dense = (np.abs(observed_distance - mapped_distance) < 0.3) & (obs[:, None] != obs) & (lm[:, None] != lm)
    edges = compatibility_graph(observed, landmarks, candidates, d_comp=0.3)
    assert set(map(tuple, edges.tolist())) == set(map(tuple, np.argwhere(np.triu(dense, 1)).tolist()))


@pytest.mark.parametrize(("seed", "nodes", "density"), [(0, 30, 0.3), (1, 60, 0.2), (2, 40, 0.6), (3, 200, 0.05)])
def test_maximal_cliques_equal_networkx(seed, nodes, density):
    rng = np.random.default_rng(seed)
    upper = np.triu(rng.random((nodes, nodes)) < density, 1)
    reference = {frozenset(c) for c in nx.find_cliques(nx.from_numpy_array((upper | upper.T).astype(int)))}
    for min_size in (1, 3):
        cliques, cap = maximal_cliques(np.argwhere(upper), nodes, min_size=min_size)
        assert cap is None
        assert len(cliques) == len({frozenset(c.tolist()) for c in cliques})
        assert {frozenset(c.tolist()) for c in cliques} == {c for c in reference if len(c) >= min_size}


def moon_moser(triangles: int) -> np.ndarray:
    """Edges of the complement of disjoint triangles: 3^triangles maximal cliques."""
    group = np.arange(3 * triangles) // 3
    return np.argwhere(np.triu(group[:, None] != group[None, :], 1))


def test_clique_caps_are_reported():
    edges = moon_moser(7)  # 2,187 maximal cliques of 7
    cliques, cap = maximal_cliques(edges, 21, max_cliques=50)
    assert cap == "max_cliques" and len(cliques) == 50
    cliques, cap = maximal_cliques(edges, 21, max_cliques=100_000, time_limit_s=1e-9)
    assert cap == "time_limit" and len(cliques) == 1_000  # the first round completes, then the clock stops it
    cliques, cap = maximal_cliques(edges, 21)
    assert cap is None and len(cliques) == 3**7


def test_rank_cliques_by_summed_similarity():
    scores = np.array([0.9, 0.1, 0.5, 0.5, 0.2])
    ranked = rank_cliques([np.array([0, 1, 4]), np.array([1, 2, 3]), np.array([0, 2, 3])], scores)
    assert [c.tolist() for c in ranked] == [[0, 2, 3], [0, 1, 4], [1, 2, 3]]


@pytest.mark.parametrize("seed", range(3))
def test_cliques_recover_a_known_pose_among_80_percent_outliers(seed):
    landmarks, observed, candidates, truth, right = outlier_heavy_problem(seed)
    edges = compatibility_graph(observed, landmarks, candidates, d_comp=0.3)
    cliques, _ = maximal_cliques(edges, len(candidates))
    best = rank_cliques(cliques, np.ones(len(candidates)))[0]
    assert best.tolist() == list(range(right))
    pose = fit_rigid(observed[candidates[best, 0]], landmarks[candidates[best, 1]])
    te, re = pose_errors(pose, truth)
    assert te < 0.05 and re < np.radians(1.0)


@pytest.mark.parametrize(("seed", "progressive"), list(itertools.product(range(3), (False, True))))
def test_sample_consensus_recovers_a_known_pose_among_80_percent_outliers(seed, progressive):
    landmarks, observed, candidates, truth, right = outlier_heavy_problem(seed)
    scores = np.where(np.arange(len(candidates)) < right, 0.8, 0.6)  # PROSAC's ordering prior
    consensus = sample_consensus(
        observed, landmarks, candidates, scores, iterations=3000, threshold=0.2,
        rng=np.random.default_rng(seed), progressive=progressive,
    )
    assert consensus.inlier_sets[0].tolist() == list(range(right))
    assert right - 2 < consensus.scores[0] <= right  # each inlier adds 1 - residual / threshold
    assert consensus.scores == sorted(consensus.scores, reverse=True)
    pose = fit_rigid(observed[candidates[consensus.inlier_sets[0], 0]],
                     landmarks[candidates[consensus.inlier_sets[0], 1]])
    te, re = pose_errors(pose, truth)
    assert te < 0.05 and re < np.radians(1.0)


def test_sample_consensus_is_seeded_and_respects_classes():
    landmarks, observed, candidates, _, right = outlier_heavy_problem(0)
    run = lambda **kw: sample_consensus(  # noqa: E731
        observed, landmarks, candidates, np.ones(len(candidates)), iterations=500, threshold=0.2,
        rng=np.random.default_rng(5), **kw,
    )
    first, second = run(), run()
    assert [s.tolist() for s in first.inlier_sets] == [s.tolist() for s in second.inlier_sets]
    same_class = np.arange(len(candidates)) >= 2  # candidates 0 and 1 disagree in class: never inliers
    for members in run(same_class=same_class).inlier_sets:
        assert not np.isin([0, 1], members).any()


def test_prosac_tries_the_best_scored_candidates_first():
    landmarks, observed, candidates, _, right = outlier_heavy_problem(1)
    scores = np.where(np.arange(len(candidates)) < right, 0.9, 0.1)
    consensus = sample_consensus(
        observed, landmarks, candidates, scores, iterations=5, threshold=0.2,
        rng=np.random.default_rng(0), progressive=True,
    )
    assert consensus.inlier_sets[0].tolist() == list(range(right))  # 5 draws suffice with the right prior


def test_too_few_candidates_give_no_consensus():
    consensus = sample_consensus(
        np.zeros((2, 3)), np.zeros((2, 3)), np.array([[0, 0], [1, 1]]), np.ones(2),
        iterations=10, threshold=0.2, rng=np.random.default_rng(0),
    )
    assert consensus.inlier_sets == [] and consensus.num_hypotheses == 0


def test_slack_widens_the_test_per_candidate():
    landmarks, observed, candidates, _, _ = outlier_heavy_problem(5)
    obs, lm = candidates[:, 0], candidates[:, 1]
    slack = np.random.default_rng(0).uniform(0, 0.4, len(candidates))
    observed_distance = np.linalg.norm(observed[obs][:, None] - observed[obs][None], axis=-1)
    mapped_distance = np.linalg.norm(landmarks[lm][:, None] - landmarks[lm][None], axis=-1)
    tolerance = 0.3 + slack[:, None] + slack[None, :]
    dense = (np.abs(observed_distance - mapped_distance) < tolerance) & (obs[:, None] != obs) & (lm[:, None] != lm)
    edges = compatibility_graph(observed, landmarks, candidates, d_comp=0.3, slack=slack)
    assert set(map(tuple, edges.tolist())) == set(map(tuple, np.argwhere(np.triu(dense, 1)).tolist()))
    plain = compatibility_graph(observed, landmarks, candidates, d_comp=0.3)
    assert len(edges) > len(plain)
    np.testing.assert_array_equal(compatibility_graph(observed, landmarks, candidates, 0.3, np.zeros(len(candidates))),
                                  plain)


def test_identical_landmarks_are_capped_to_the_pair_budget_best_scored_first():
    landmarks = np.zeros((3000, 3))  # 3,000 identical overlapping landmarks: 4.5 million pairs in reach
    observed = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0.0]])
    candidates = np.column_stack((np.arange(3000) % 3, np.arange(3000)))
    scores = np.linspace(1.0, 0.0, 3000)
    kept = affordable_candidates(observed, landmarks, candidates, scores, 0.3, max_pairs=10_000)
    assert len(kept) == 141  # 141 * 140 / 2 = 9,870 pairs; 142 would make 10,011
    np.testing.assert_array_equal(kept, np.arange(len(kept)))  # the best-scored ones
    assert len(compatibility_graph(observed, landmarks, candidates[kept], 0.3)) <= 10_000
    few = affordable_candidates(observed, landmarks, candidates[:50], scores[:50], 0.3, max_pairs=10_000)
    np.testing.assert_array_equal(few, np.arange(50))


def test_two_observations_of_one_object_are_never_compatible():
    # observations 0 and 1 are one cup detected twice (a cross-class duplicate); 2 and 3 are other objects
    observed = np.array([[0, 0, 0], [0.01, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    landmarks = np.array([[0, 0, 0], [0.02, 0, 0], [1, 0, 0], [0, 1, 0.0]])  # two cups side by side
    candidates = np.array([[0, 0], [1, 1], [2, 2], [3, 3]])
    apart = set(map(tuple, compatibility_graph(observed, landmarks, candidates, d_comp=0.3).tolist()))
    assert (0, 1) in apart  # as two objects, each matches one of the cups, in one clique
    merged = compatibility_graph(observed, landmarks, candidates, d_comp=0.3, objects=np.array([0, 0, 2, 3]))
    assert set(map(tuple, merged.tolist())) == apart - {(0, 1)}


def test_the_grid_bound_never_counts_fewer_pairs_than_lie_within_reach():
    """The cheap bound may only skip the exact count when the exact count fits too: it must never be below it."""
    from clipclique.inliers.compatibility import _pairs_bound, _pairs_within

    rng = np.random.default_rng(5)
    for trial in range(300):
        count, reach = int(rng.integers(2, 400)), float(rng.choice([0.05, 0.5, 1.0, 3.0]))
        points = rng.uniform(-5, 5, (count, 3)) * rng.uniform(0.1, 3, 3)
        if trial % 3 == 0:  # a grid of spacing `reach`: pairs exactly at the reach, on cell borders
            points = np.round(points / reach) * reach
        if trial % 5 == 0:  # far-apart rooms: the bound is close to the count
            points += 20.0 * rng.integers(0, 10, (count, 1))
        exact, bound = _pairs_within(points, reach), _pairs_bound(points, reach)
        assert exact <= bound <= count * (count - 1) // 2
    rooms = rng.uniform(0, 3, (50, 3))[None] + 20.0 * np.arange(100)[:, None, None]  # 100 rooms of 50 within reach
    assert _pairs_bound(rooms.reshape(-1, 3), 4.0) <= 8 * _pairs_within(rooms.reshape(-1, 3), 4.0)


def test_pair_distances_are_numpys_norm():
    """`compatibility.pair_distances` against np.linalg.norm of the differences, within rounding, on hand-made centres
    (-0, equal points, NaN, infinities, huge and tiny values) and random ones, and no centres."""
    from clipclique.inliers.compatibility import pair_distances

    hand = np.array([[0.0, -0.0, 0.0], [-0.0, 0.0, -0.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [np.nan, 0.0, 1.0],
                     [np.inf, 1.0, 0.0], [-np.inf, 0.0, 0.0], [1e200, 1e-200, 3.0], [0.1, 0.2, 0.3],
                     [5e-324, 0.0, 1.0]])
    rng = np.random.default_rng(0)
    for centers in (hand, rng.normal(size=(40, 3)) * 10.0 ** rng.integers(-3, 4, (40, 1)), np.zeros((0, 3)),
                    np.asfortranarray(rng.normal(size=(7, 3)))):
        with np.errstate(invalid="ignore", over="ignore"):
            expected = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
        got = pair_distances(centers)
        assert got.shape == expected.shape and got.dtype == np.float64
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-300)


def test_partial_view_slack_is_the_numpy_passes():
    """The compiled slack against the numpy expression it replaced, on hand-made semi-axes (ties, -0, NaN in either
    side, infinities, deficits exactly at min_deficit and slack exactly at the cap) and random ones, no candidates."""
    from clipclique.inliers.compatibility import partial_view_slack

    def numpy_slack(observed, mapped, fraction, cap, min_deficit):
        deficit = (np.sort(mapped, axis=1) - np.sort(observed, axis=1)).max(axis=1)
        return np.where(deficit >= min_deficit, np.minimum(fraction * deficit, cap), 0.0)

    nan, inf = np.nan, np.inf
    observed = np.array([[0.1, 0.2, 0.3], [0.3, 0.1, 0.2], [0.2, 0.2, 0.2], [-0.0, 0.0, 0.1], [nan, 0.1, 0.2],
                         [0.1, 0.2, 0.3], [inf, 0.1, 0.1], [0.1, 0.1, 0.1], [0.05, 0.1, 0.1], [0.1, nan, nan]])
    mapped = np.array([[0.3, 0.2, 0.1], [0.5, 0.1, 0.2], [0.2, 0.2, 0.2], [0.0, -0.0, 0.1], [0.1, 0.2, 0.3],
                       [0.1, nan, 0.3], [0.1, inf, 0.1], [0.2, 0.1, 0.1], [0.45, 0.1, 0.1], [nan, 0.1, nan]])
    rng = np.random.default_rng(5)
    random = np.round(rng.uniform(0, 0.5, (300, 3)), 2), np.round(rng.uniform(0, 0.5, (300, 3)), 2)
    cases = [(observed, mapped), random, (np.zeros((0, 3)), np.zeros((0, 3)))]
    for observed, mapped in cases:
        for fraction, cap, min_deficit in ((0.5, 0.05, 0.1), (1.0, 0.2, 0.0), (0.25, 0.0, 0.05), (0.0, 0.1, 0.1),
                                           (0.5, 0.1, -inf)):
            with np.errstate(invalid="ignore"):
                expected = numpy_slack(observed, mapped, fraction, cap, min_deficit)
                got = partial_view_slack(observed, mapped, fraction, cap, min_deficit)
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12, err_msg=str((fraction, cap, min_deficit)))


def test_candidate_slack_is_the_slack_of_the_gathered_rows():
    """`candidate_slack` reads each candidate's rows where they lie: the same numbers as `partial_view_slack` of the
    gathered rows, on candidates repeating rows, axes with NaN, a fraction of 0 and no candidates."""
    from clipclique.inliers.compatibility import candidate_slack, partial_view_slack

    rng = np.random.default_rng(23)
    observed, mapped = rng.uniform(0.0, 0.5, (6, 3)), rng.uniform(0.0, 0.9, (15, 3))
    observed[2, 1], mapped[4, 0] = np.nan, np.nan
    for count in (0, 1, 7, 40):
        candidates = np.column_stack((rng.integers(0, 6, count), rng.integers(0, 15, count))).astype(np.int64)
        for fraction, cap, min_deficit in [(0.5, 0.3, 0.05), (1.0, 0.6, 0.0), (0.0, 0.6, 0.3)]:
            expected = partial_view_slack(observed[candidates[:, 0]], mapped[candidates[:, 1]], fraction, cap,
                                          min_deficit)
            got = candidate_slack(observed, mapped, candidates, fraction, cap, min_deficit)
            np.testing.assert_array_equal(got, expected)
            assert count < 40 or fraction == 0 or (got > 0).sum() > 10


def lexicographic(pairs: np.ndarray) -> np.ndarray:
    """Pairs (P, 2) in order of their first index, then their second."""
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def test_pairs_in_reach_are_the_kd_trees():
    """`compatibility._pairs_in_reach` (every pair tested by a compiled pass, listed i then j, up to ALL_PAIRS_UP_TO
    points; the tree, in its order, beyond) against `cKDTree.query_pairs`, pair for pair: random, rounded and
    repeated points of 0 to 20 and about ALL_PAIRS_UP_TO (past it), reaches exactly at a pair's distance and one
    step either side of it, 0, negative, NaN and infinite; and the tree's ValueError for a point that is not
    finite."""
    from scipy.spatial import cKDTree

    from clipclique.inliers.compatibility import ALL_PAIRS_UP_TO, _pairs_in_reach

    rng = np.random.default_rng(21)
    at_boundary = 0
    for trial in range(3000):
        count = int(rng.integers(0, 21) if trial % 10 else rng.integers(ALL_PAIRS_UP_TO - 4, ALL_PAIRS_UP_TO + 4))
        points = rng.normal(size=(count, 3)) * 10.0 ** rng.integers(-3, 4)
        if trial % 3 == 0:
            points = np.round(points, 1)  # equal distances
        if count > 1 and trial % 5 == 0:
            points[1] = points[0]  # one point twice
        reaches = [0.0, -1.0, np.nan, np.inf, float(rng.uniform(0, 3))]
        if count > 1:
            i, j = rng.choice(count, 2, replace=False)
            dx, dy, dz = points[i] - points[j]
            exact = float(np.sqrt((dx * dx + dy * dy) + dz * dz))
            reaches += [exact, float(np.nextafter(exact, 0.0)), float(np.nextafter(exact, np.inf))]
        for reach in reaches:
            expected = cKDTree(points).query_pairs(reach, output_type="ndarray").astype(np.int64)
            got = _pairs_in_reach(points, reach)
            assert got.dtype == np.int64
            np.testing.assert_array_equal(got, lexicographic(expected) if count <= ALL_PAIRS_UP_TO else expected)
        at_boundary += count > 1
    assert at_boundary > 2000
    for bad in (np.nan, np.inf, -np.inf):
        for count in (3, ALL_PAIRS_UP_TO + 2):
            points = rng.normal(size=(count, 3))
            points[count // 2, 1] = bad
            with pytest.raises(ValueError) as ours:
                _pairs_in_reach(points, 1.0)
            with pytest.raises(ValueError) as trees:
                cKDTree(points)
            assert str(ours.value) == str(trees.value)


def test_compatibility_graph_lists_the_kd_trees_pairs_in_order():
    """`compatibility_graph` against the graph of every pair the tree lists, i then j, filtered by the rigid test in
    that order (the clique search orders equal candidates by it), on frames of 2 to 30 candidates with slack and
    objects."""
    from scipy.spatial import cKDTree

    from clipclique.inliers.compatibility import _compatible, pair_distances, pair_reach

    rng = np.random.default_rng(22)
    for trial in range(400):
        count, observations = int(rng.integers(2, 31)), int(rng.integers(2, 9))
        observed, landmarks = rng.uniform(0, 3, (observations, 3)), np.round(rng.uniform(0, 3, (12, 3)), 1)
        candidates = np.column_stack((rng.integers(0, observations, count), rng.integers(0, 12, count)))
        slack = np.where(rng.random(count) < 0.3, rng.uniform(0, 0.2, count), 0.0)
        objects = np.minimum(np.arange(observations), rng.integers(0, observations, observations))
        objects = objects[objects]  # an observation's object shows its own
        distances, points = pair_distances(observed), landmarks[candidates[:, 1]]
        pairs = lexicographic(cKDTree(points).query_pairs(pair_reach(distances, 0.3, slack), output_type="ndarray")
                              .astype(np.int64))
        expected = _compatible(pairs, points, candidates[:, 0], objects[candidates[:, 0]], candidates[:, 1], distances,
                               0.3, slack)
        got = compatibility_graph(observed, landmarks, candidates, 0.3, slack, objects)
        assert got.dtype == expected.dtype
        np.testing.assert_array_equal(got, expected)


def test_pair_reach_is_the_numpy_expression():
    """`compatibility.pair_reach` against the numpy expression it replaced: NaN and infinities in either array,
    no or empty slack, a single distance, float32 distances, and numpy's ValueError for no distances."""
    from clipclique.inliers.compatibility import pair_reach

    def numpy_reach(observed, d_comp, slack):
        widest = 0.0 if slack is None or len(slack) == 0 else 2.0 * float(slack.max())
        return float(observed.max()) + d_comp + widest

    rng = np.random.default_rng(23)
    distances = [rng.uniform(0, 5, (6, 6)), np.zeros((1, 1)), rng.uniform(0, 5, (4, 4)).astype(np.float32),
                 np.array([[0.0, np.nan], [np.nan, 0.0]]), np.array([[0.0, np.inf], [np.inf, 0.0]]),
                 np.array([[0.0, 1.0, np.nan], [1.0, 0.0, 7.0], [np.nan, 7.0, 0.0]])]
    slacks = [None, np.zeros(0), np.zeros(5), rng.uniform(0, 0.2, 5), np.array([0.1, np.nan, 0.2]),
              np.array([np.nan, 0.3]), np.array([np.inf, 0.1]), np.array([-np.inf])]
    for observed in distances:
        for slack in slacks:
            for d_comp in (0.3, 0.0, 1):
                got, expected = pair_reach(observed, d_comp, slack), numpy_reach(observed, d_comp, slack)
                assert type(got) is float
                np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="zero-size array"):
        pair_reach(np.zeros((0, 0)), 0.3, None)
