"""Verification's wiring: every hypothesis of the inlier stage's pool verified in the image
(clipclique.verify.verification) and given a calibrated confidence (clipclique.verify.confidence), the pool
re-ranked by either (`inliers.rerank`) to its top_n, and `min_confidence` applied.

It exists so that `clipclique.pipeline` stays the composition of the stages: what verification may read of
a window's observations (those with a box in the query image) and how its scores reorder the hypotheses
live here, below the inlier stage, which asks `reranked` how large a pool to fit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numba import njit

from clipclique.config import LocalizationConfig
from clipclique.errors import ClipcliqueError
from clipclique.outcomes import Failure, FailureKind, LocalizationResult
from clipclique.pose.stack import Stack
from clipclique.types import Map, Observations
from clipclique.verify import confidence, verification

# Re-ranking keys equal to this many decimals tie, and ties keep the pool's order (the clique score's): the same
# correspondences in another order fit a pose that differs in its last bits, and so does its verification score.
RANK_DECIMALS = 9
_RANK_SCALE = 10.0**RANK_DECIMALS


def reranked(observations: Observations, config: LocalizationConfig) -> bool:
    """Whether the hypotheses will be re-ranked in the image (`inliers.rerank`, boxes and camera given)."""
    return config.inliers.rerank != "none" and observations.boxes is not None and observations.camera is not None


def verify_pool(result: LocalizationResult, pool: Stack, observations: Observations, map: Map,
                spreads: np.ndarray | None, config: LocalizationConfig) -> None:
    """Verification score and confidence of every hypothesis of the pool, then `inliers.rerank` and
    `min_confidence`: `result.hypotheses`, the kept ones built from the stack.

    Observations without boxes and camera (a library caller's own) are left unverified and in the
    clique score's order (a note says so), unless a confidence floor asks for verification.
    """
    if observations.boxes is None or observations.camera is None:
        if config.min_confidence > 0:
            verification.require_image(observations, "min_confidence")
        if config.inliers.rerank != "none" and len(pool):
            result.notes.append(f"no boxes or camera: inliers.rerank = {config.inliers.rerank} not applied")
        result.hypotheses = pool.hypotheses()
        return
    if not len(pool):
        return
    seen, narrowed, similarity_seen = with_boxes(observations, pool, result.similarity)
    checked = verification.verify_stack(narrowed, seen, map, config.verification, spreads)
    model = confidence.load_model(config.confidence_model)
    probability = (None if model is None else
                   model.predict(confidence.Evidence(narrowed, checked, similarity_seen, len(seen))))
    kept = None
    if config.inliers.rerank != "none":
        if config.inliers.rerank == "confidence" and probability is None:
            raise ClipcliqueError(
                "inliers.rerank = confidence needs a confidence model (none is shipped in this build)")
        key = checked.score if config.inliers.rerank == "verification" else probability
        kept = best_first(key, config.top_n)
    result.hypotheses = pool.hypotheses(kept, checked.score, probability)
    if config.min_confidence > 0:
        if probability is None:
            raise ClipcliqueError("min_confidence needs a confidence model (none is shipped in this build)")
        best = max(h.confidence for h in result.hypotheses)
        result.hypotheses = [h for h in result.hypotheses if h.confidence >= config.min_confidence]
        if not result.hypotheses:
            result.failure = Failure(kind=FailureKind.NOT_CONFIDENT, min_confidence=config.min_confidence,
                                     best_confidence=best)


def best_first(key: np.ndarray, top_n: int) -> np.ndarray:
    """The rows of the top_n largest keys rounded to RANK_DECIMALS, best first, ties in the pool's order and NaN
    last: the first top_n of `np.argsort(-np.round(key, RANK_DECIMALS), kind="stable")`, by a compiled selection
    (`_best_first`; a frame keeps 5 of 50, and numpy's round, negation and sort cost more than the work)."""
    return _best_first(np.asarray(key, np.float64), int(top_n))


@njit(cache=True)
def _best_first(key: np.ndarray, top_n: int) -> np.ndarray:
    """`best_first`: each key rounded as numpy rounds to RANK_DECIMALS (times 10^d, to the nearest even, over
    10^d), then top_n times the first largest of those not taken yet (a NaN only where nothing else is left)."""
    rounded = np.empty(len(key))
    for b in range(len(key)):
        rounded[b] = np.rint(key[b] * _RANK_SCALE) / _RANK_SCALE
    kept, taken = np.empty(min(top_n, len(key)), np.int64), np.zeros(len(key), np.bool_)
    for r in range(len(kept)):
        best = -1
        for b in range(len(key)):
            if not taken[b] and (best < 0 or rounded[b] > rounded[best]
                                 or (np.isnan(rounded[best]) and not np.isnan(rounded[b]))):
                best = b
        taken[best], kept[r] = True, best
    return kept


def with_boxes(observations: Observations, pool: Stack,
                similarity: np.ndarray) -> tuple[Observations, Stack, np.ndarray]:
    """What verification and confidence may read: the observations with a box in the query image, each
    hypothesis with its correspondences among them (renumbered), and their rows of the similarity.
    Unchanged when every observation has a box (a single frame)."""
    if observations.has_box is None or observations.has_box.all():
        return observations, pool, similarity
    kept = np.flatnonzero(observations.has_box)
    renumber = np.full(len(observations), -1)
    renumber[kept] = np.arange(len(kept))
    boxed = observations.has_box[pool.pairs[:, 0]]
    pairs = pool.pairs[boxed]
    narrowed = replace(pool, pairs=np.column_stack((renumber[pairs[:, 0]], pairs[:, 1])),
                       counts=np.bincount(pool.owners()[boxed], minlength=len(pool)))
    return observations.subset(kept), narrowed, similarity[kept]
