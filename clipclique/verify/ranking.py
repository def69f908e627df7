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
    model = confidence.load_model(config.confidence_model)
    if model is None and (config.inliers.rerank == "confidence" or config.min_confidence > 0):
        why = "inliers.rerank = confidence" if config.inliers.rerank == "confidence" else "min_confidence"
        raise ClipcliqueError(f"{why} needs a confidence model (none is shipped in this build)")
    seen, narrowed, similarity_seen = with_boxes(observations, pool, result.similarity)
    kept, figures = _ranked(_RERANK[config.inliers.rerank], int(config.top_n),
                            *verification.figure_inputs(narrowed, seen, map, config.verification, spreads),
                            similarity_seen, float(len(seen)), model is not None,
                            *(_NO_MODEL if model is None else model.terms()))
    verified, confident = figures.tolist()
    result.hypotheses = pool.hypotheses(kept, verified, None if model is None else confident)
    if config.min_confidence > 0:
        best = max(h.confidence for h in result.hypotheses)
        result.hypotheses = [h for h in result.hypotheses if h.confidence >= config.min_confidence]
        if not result.hypotheses:
            result.failure = Failure(kind=FailureKind.NOT_CONFIDENT, min_confidence=config.min_confidence,
                                     best_confidence=best)


_RERANK = {"none": 0, "verification": 1, "confidence": 2}  # `inliers.rerank` as `_ranked` reads it
_NO_MODEL = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0), 0.0, 0.0, 0.0)  # `_ranked`'s model terms
_NO_MODEL[0].flags.writeable = False  # as a model's columns (`ConfidenceModel.terms`): one compiled signature


@njit(cache=True)
def _ranked(rerank, top_n, rotations, translations, pairs, counts, centers, axes, spreads, boxes, observed_centers,
            class_ids, detected_classes, intrinsics, width, height, max_depth, depth_tolerance, min_pixels,
            explained_iou, full, missed_weight, share_from, similarity, num_observations, modelled, columns, mean,
            scale, coefficients, intercept, slope, offset):
    """`verify_pool`'s work in one compiled call (a small query's compiled calls and the arrays each hands back cost
    more than its arithmetic): the figures (`verification.figures`), the rows kept (rerank 0: all, in pool order; 1:
    `best_first` of the verification scores; 2: of the confidences) and (2, kept) their verification scores and
    confidences (NaN without a model, `modelled` False). Re-ranked by verification, only the kept rows' confidences
    are computed (each row's is its own, from the frame's figures)."""
    score, overlap, mean_iou, missed, _, _, depth_error = verification.figures(
        rotations, translations, pairs, counts, centers, axes, spreads, boxes, observed_centers, class_ids,
        detected_classes, intrinsics, width, height, max_depth, depth_tolerance, min_pixels, explained_iou, full,
        missed_weight, share_from)
    kept = _best_first(score, top_n) if rerank == 1 else np.arange(len(score))
    probability = np.full(len(kept), np.nan)
    if modelled:
        probability = confidence.probabilities(kept, overlap, score, mean_iou, missed, depth_error, missed_weight,
                                               counts, pairs, similarity, num_observations, columns, mean, scale,
                                               coefficients, intercept, slope, offset)
        if rerank == 2:
            kept = _best_first(probability, top_n)
            probability = probability[kept]
    out = np.empty((2, len(kept)))
    for r in range(len(kept)):
        out[0, r], out[1, r] = score[kept[r]], probability[r]
    return kept, out


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
