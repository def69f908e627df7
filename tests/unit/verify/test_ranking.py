"""Verification's wiring (clipclique.verify.ranking): what verification may read of a window's observations, when
the pool is re-ranked, and a pool left unverified where the observations carry no boxes or camera."""

import numpy as np

from clipclique.config import make_config
from clipclique.inliers.hypotheses import from_cliques
from clipclique.outcomes import LocalizationResult
from clipclique.pipeline import index_map, localize
from clipclique.pose.stack import Stack
from clipclique.sim.synthetic import synthetic_map, synthetic_query
from clipclique.verify.ranking import RANK_DECIMALS, best_first, reranked, verify_pool, with_boxes


def pool_of(rows: list[list[tuple[int, int]]]) -> Stack:
    """A stack of identity poses holding these correspondences, hypothesis after hypothesis."""
    count = len(rows)
    return Stack(rotations=np.tile(np.eye(3), (count, 1, 1)), translations=np.zeros((count, 3)),
                 pairs=np.array([pair for row in rows for pair in row], np.int64).reshape(-1, 2),
                 counts=np.array([len(row) for row in rows], np.int64), scores=np.arange(count, 0, -1.0),
                 conditioning=np.ones(count))


def test_observations_without_a_box_leave_verification_renumbered():
    rng = np.random.default_rng(5)
    map = synthetic_map(rng, num_landmarks=20)
    query, _ = synthetic_query(map, rng, num_visible=6, num_outliers=0)
    similarity = rng.random((len(query), len(map)))
    pool = pool_of([[(0, 4), (2, 7), (3, 1), (5, 2)], [(1, 3), (2, 9), (4, 0)]])
    assert all(part is whole for part, whole in zip(with_boxes(query, pool, similarity), (query, pool, similarity)))
    query.has_box = np.array([True, False, True, True, False, True])  # 1 and 4 seen only by older frames
    seen, narrowed, rows = with_boxes(query, pool, similarity)
    assert len(seen) == 4 and narrowed.counts.tolist() == [4, 1]
    assert narrowed.pairs.tolist() == [[0, 4], [1, 7], [2, 1], [3, 2], [1, 9]]  # renumbered among the boxed
    np.testing.assert_array_equal(rows, similarity[[0, 2, 3, 5]])
    np.testing.assert_array_equal(seen.ellipsoids.centers, query.ellipsoids.centers[[0, 2, 3, 5]])


def test_the_pool_is_reranked_only_with_boxes_and_camera():
    rng = np.random.default_rng(2)
    map = synthetic_map(rng, num_landmarks=20)
    query, _ = synthetic_query(map, rng)
    assert query.boxes is not None and query.camera is not None
    assert reranked(query, make_config("clipclique"))
    assert not reranked(query, make_config("clipclique", overrides=["inliers.rerank=none"]))
    query.camera = None
    assert not reranked(query, make_config("clipclique"))


def test_a_pool_without_boxes_keeps_the_clique_order_unverified():
    rng = np.random.default_rng(4)
    map = synthetic_map(rng, num_landmarks=30)
    query, _ = synthetic_query(map, rng, num_visible=10, num_outliers=0)
    config = make_config("clipclique")
    found = localize(query, index_map(map, config), config)
    query.boxes = None
    result = LocalizationResult(hypotheses=[], candidates=found.candidates, candidate_scores=found.candidate_scores,
                                similarity=found.similarity, num_cliques=0, cap_hit=None, failure=None)
    pool = from_cliques(result, query, map, config, lambda stage: None)
    assert len(pool)
    verify_pool(result, pool, query, map, None, config)
    assert [h.score for h in result.hypotheses] == pool.scores.tolist()
    assert all(h.verification is None for h in result.hypotheses)
    assert result.notes == ["no boxes or camera: inliers.rerank = verification not applied"]


def test_the_best_first_are_numpys_stable_sort_of_the_rounded_keys():
    """`best_first` against `np.argsort(-np.round(key, RANK_DECIMALS), kind="stable")[:top_n]`: keys tied once
    rounded (1e-10 apart), exactly tied, +0 and -0, infinities and NaN (last, in the pool's order), a pool smaller
    than top_n, none."""
    rng = np.random.default_rng(13)
    for trial in range(500):
        count = int(rng.choice([0, 1, 2, 5, 50, 80]))
        key = np.round(rng.normal(size=count), int(rng.integers(0, 3)))
        spots = rng.integers(0, max(count, 1), size=min(count, 6))
        key[spots[:2]] = key[spots[:2]] + 1e-10 * rng.normal(size=len(spots[:2]))
        key[spots[2:]] = rng.choice([0.0, -0.0, np.inf, -np.inf, np.nan], size=len(spots[2:]))
        top_n = int(rng.choice([1, 5, 10, 100]))
        expected = np.argsort(-np.round(key, RANK_DECIMALS), kind="stable")[:top_n]
        assert best_first(key, top_n).tolist() == expected.tolist(), (key, top_n)
