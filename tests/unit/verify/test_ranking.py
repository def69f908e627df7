"""Verification's wiring (clipclique.verify.ranking): what verification may read of a window's observations, when
the pool is re-ranked, and a pool left unverified where the observations carry no boxes or camera."""

import numpy as np
import pytest

from clipclique.config import make_config
from clipclique.errors import ClipcliqueError
from clipclique.inliers.hypotheses import from_cliques
from clipclique.outcomes import LocalizationResult
from clipclique.pipeline import index_map, localize
from clipclique.pose.stack import Stack
from clipclique.sim.synthetic import synthetic_map, synthetic_query
from clipclique.verify import confidence, verification
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


@pytest.mark.parametrize("rerank", ["none", "verification", "confidence"])
def test_the_pool_verified_in_one_call_is_its_steps_one_by_one(rerank, monkeypatch):
    """`verify_pool`'s one compiled call against its steps: `verify_stack` of the whole pool, the model's `predict`
    of it, `best_first` of the re-ranking key (all rows in pool order without one): the same rows, verification
    scores and confidences to the bit, pools with hypotheses alike (ties) and top_n above and below their size; with
    no model, no confidence (and re-ranking by it refused)."""
    rng = np.random.default_rng(17)
    checked_rows = 0
    for trial in range(12):
        map = synthetic_map(rng, num_landmarks=30)
        query, _ = synthetic_query(map, rng, num_visible=9, num_outliers=2)
        top_n = int(rng.choice([1, 5, 50]))
        config = make_config("clipclique", overrides=[f"inliers.rerank={rerank}", f"top_n={top_n}"])
        found = localize(query, index_map(map, config), config)
        result = LocalizationResult(hypotheses=[], candidates=found.candidates,
                                    candidate_scores=found.candidate_scores, similarity=found.similarity,
                                    num_cliques=0, cap_hit=None, failure=None)
        pool = from_cliques(result, query, map, config, lambda stage: None)
        moved = pool.take(rng.integers(0, len(pool), 30))  # poses around the cliques', some exactly alike
        moved.translations = moved.translations + rng.choice([0.0, 0.05, 0.3], (30, 1)) * rng.normal(size=(30, 3))
        pool = Stack.joined([pool, moved])
        checked = verification.verify_stack(pool, query, map, config.verification)
        probability = confidence.load_model().predict(confidence.Evidence(pool, checked, found.similarity,
                                                                          len(query)))
        key = {"none": None, "verification": checked.score, "confidence": probability}[rerank]
        kept = np.arange(len(pool)) if key is None else best_first(key, top_n)
        verify_pool(result, pool, query, map, None, config)
        assert [(h.score, h.verification, h.confidence) for h in result.hypotheses] == list(
            zip(pool.scores[kept].tolist(), checked.score[kept].tolist(), probability[kept].tolist()))
        for got, row in zip(result.hypotheses, kept.tolist()):
            np.testing.assert_array_equal(got.pose.rotation, pool.rotations[row])
            np.testing.assert_array_equal(got.correspondences, pool.take(np.array([row])).pairs)
        checked_rows += len(kept)
    assert checked_rows > 100
    monkeypatch.setattr(confidence, "load_model", lambda path="": None)
    config = make_config("clipclique", overrides=[f"inliers.rerank={rerank}"])
    if rerank == "confidence":
        with pytest.raises(ClipcliqueError, match="needs a confidence model"):
            verify_pool(result, pool, query, map, None, config)
        return
    verify_pool(result, pool, query, map, None, config)
    assert result.hypotheses and all(h.confidence is None for h in result.hypotheses)
    key = checked.score if rerank == "verification" else None
    kept = np.arange(len(pool)) if key is None else best_first(key, config.top_n)
    assert [h.verification for h in result.hypotheses] == checked.score[kept].tolist()
