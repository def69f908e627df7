"""Weighted closed-form rigid alignment (Kabsch/Umeyama without scale), Umeyama with scale, and the weights.

Given camera-frame observation centres `p_i`, map landmark centres `q_i` and weights `w_i >= 0`,
the pose minimizes `sum_i w_i |R p_i + t - q_i|^2`: weighted centroids, the SVD of the weighted
cross-covariance, and a sign fix so that `det R = +1` (never a reflection). Inputs that cannot fix
a 6-DoF pose (fewer than 3 points, collinear points, zero weights) raise `DegeneratePoseError`
with the reason; the solver never returns NaN.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit

from clipclique.config import PoseWeights
from clipclique.types import Pose

MIN_SPREAD_M = 1e-6  # metres: a point set thinner than this across its second axis is collinear
RELATIVE_SPREAD = 1e-6  # ... or thinner than this fraction of its length
_MIN_VARIANCE, _RELATIVE_VARIANCE = MIN_SPREAD_M**2, RELATIVE_SPREAD**2


class DegeneratePoseError(ValueError):
    """The correspondences cannot determine a rigid pose; the message says why."""


def fit_rigid(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> Pose:
    """The pose `x -> R x + t` that best maps `source` (P, 3) onto `target` (P, 3) in weighted least squares."""
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise ValueError(f"source {source.shape} and target {target.shape} must both be (P, 3)")
    weights = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=np.float64)
    if weights.shape != (len(source),) or not np.isfinite(weights).all() or (weights < 0).any():
        raise DegeneratePoseError("weights must be finite, non-negative, one per point")
    if len(source) < 3:
        raise DegeneratePoseError(f"fewer than 3 correspondences ({len(source)})")
    if np.count_nonzero(weights) < 3:
        raise DegeneratePoseError(f"fewer than 3 correspondences with a positive weight ({np.count_nonzero(weights)})")
    rotation, translation, ok = fit_rigid_batch(source[None], target[None], weights[None])
    if not ok[0]:
        raise DegeneratePoseError("collinear points: the rotation about their line is undetermined")
    return Pose(rotation[0], translation[0])


@dataclass(frozen=True)
class Similarity:
    """`x -> scale * R x + t`: a rigid pose with one scale, what aligns a monocular map to metric ground truth."""

    scale: float
    pose: Pose

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.pose.apply(self.scale * np.asarray(points, dtype=np.float64))

    def matrix(self) -> np.ndarray:
        out = self.pose.matrix()
        out[:3, :3] *= self.scale
        return out


def fit_similarity(source: np.ndarray, target: np.ndarray, with_scale: bool = True) -> Similarity:
    """Umeyama (1991): the similarity (or, `with_scale=False`, the rigid pose with scale 1) that best maps
    `source` (P, 3) onto `target` (P, 3) in least squares. The one implementation behind map alignment
    to ground truth and trajectory alignment; degenerate inputs raise `DegeneratePoseError`."""
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    pose = fit_rigid(source, target)  # validates shapes, counts and collinearity
    if not with_scale:
        return Similarity(1.0, pose)
    centred = source - source.mean(axis=0)
    variance = float(np.einsum("ij,ij->", centred, centred)) / len(source)
    cross = (target - target.mean(axis=0)).T @ centred / len(source)
    singular = np.linalg.svd(cross, compute_uv=False)
    sign = np.sign(np.linalg.det(cross)) or 1.0
    scale = float(singular[0] + singular[1] + sign * singular[2]) / variance
    if not np.isfinite(scale) or scale <= 0:
        raise DegeneratePoseError(f"no positive scale maps the source onto the target (scale {scale:g})")
    translation = target.mean(axis=0) - scale * pose.rotation @ source.mean(axis=0)
    return Similarity(scale, Pose(pose.rotation, translation))


def fit_rigid_batch(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """B independent fits at once: (B, P, 3) points, (B, P) weights -> R (B, 3, 3), t (B, 3), ok (B,).

    `ok` is False where a set is degenerate (collinear, or weights summing to zero); those rows
    hold the identity so that callers can mask them without meeting NaN.
    """
    weights = np.ones(np.shape(source)[:2]) if weights is None else weights
    rotation, translation, ok, _ = fit_rigid_conditioned(source, target, weights)
    return rotation, translation, ok


def fit_rigid_conditioned(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_batch` and, per set, the smaller of the two sides' `conditioning`, both read off the
    same weighted covariances (a query's poses need both: measuring them apart doubled the work).

    Compiled passes around LAPACK's SVD of the cross-covariances and one eigvalsh call for both sides'."""
    weights = np.asarray(weights)
    total = weights.sum(axis=1)  # numpy's pairwise sum: the kernels add in order, as einsum does
    source, target = np.ascontiguousarray(source, np.float64), np.ascontiguousarray(target, np.float64)
    mean_source, mean_target, cross, spreads = _moments(np.ascontiguousarray(weights, np.float64), total, source,
                                                        target)
    u, _, vt = _svd(cross)
    _proper(u, vt)
    rotation = u @ vt
    variances = _eigvalsh(spreads)  # (2, B, 3)
    translation = mean_target - np.einsum("bij,bj->bi", rotation, mean_source)
    ok, measure = _settled(rotation, translation, total, variances[0], variances[1])
    return rotation, translation, ok, measure


@njit(cache=True)
def _moments(weights: np.ndarray, total: np.ndarray, source: np.ndarray,
             target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per set b, with w = weights / total (1 where the total is not positive): the weighted means of
    source and target, the cross-covariance sum_p w_p t_p s_p^T and (2, B, 3, 3) either side's covariance
    (source first), of the centred points. Each sum adds its terms in order from 0, each term
    (w_p * x_i) * y_j, as `np.einsum("bp,bpi,bpj->bij", ...)` does: the same bits in one call instead of a dozen."""
    count, points = weights.shape
    mean_source, mean_target = np.zeros((count, 3)), np.zeros((count, 3))
    cross, spreads = np.zeros((count, 3, 3)), np.zeros((2, count, 3, 3))
    w = np.empty(points)
    centred_source, centred_target = np.empty((points, 3)), np.empty((points, 3))
    for b in range(count):
        safe = total[b] if total[b] > 0 else 1.0
        for p in range(points):
            w[p] = weights[b, p] / safe
        for p in range(points):
            for i in range(3):
                mean_source[b, i] += w[p] * source[b, p, i]
                mean_target[b, i] += w[p] * target[b, p, i]
        for p in range(points):
            for i in range(3):
                centred_source[p, i] = source[b, p, i] - mean_source[b, i]
                centred_target[p, i] = target[b, p, i] - mean_target[b, i]
        for p in range(points):
            for i in range(3):
                for j in range(3):
                    cross[b, i, j] += w[p] * centred_target[p, i] * centred_source[p, j]
                    spreads[0, b, i, j] += w[p] * centred_source[p, i] * centred_source[p, j]
                    spreads[1, b, i, j] += w[p] * centred_target[p, i] * centred_target[p, j]
    return mean_source, mean_target, cross, spreads


@njit(cache=True)
def _proper(u: np.ndarray, vt: np.ndarray) -> None:
    """In place, u's third column negated where u vt is a reflection, so that u vt is a rotation: what
    `u[:, :, 2] *= np.where(sign == 0, 1, sign)` with `sign = np.sign(np.linalg.det(u @ vt))` does, without the
    product and LAPACK's determinant. The SVD's u and vt are orthogonal, so det(u) det(vt) and det(u vt) are both
    +-1 to within round-off and never 0: the same sign, and NaN alike where the SVD gave NaN (then the sets'
    covariances are not finite either, and `_settled` replaces the rotation)."""
    for b in range(len(u)):
        sign = np.sign(_det3(u[b]) * _det3(vt[b]))
        factor = 1.0 if sign == 0 else sign
        for i in range(3):
            u[b, i, 2] *= factor


@njit(cache=True)
def _det3(m: np.ndarray) -> float:
    """A 3 x 3 determinant by cofactors (its sign is what `_proper` reads)."""
    return (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
            + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))


@njit(cache=True)
def _settled(rotation: np.ndarray, translation: np.ndarray, total: np.ndarray, source_variances: np.ndarray,
             target_variances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B,) whether each set fixes a pose (positive weights, neither side collinear), and (B,) the smaller of
    the two sides' `_ratio`, np.minimum's way; a set that fixes none gets the identity, in place."""
    ok, measure = np.empty(len(total), np.bool_), np.empty(len(total))
    for b in range(len(total)):
        ok[b] = total[b] > 0 and _spread_ok(source_variances[b]) and _spread_ok(target_variances[b])
        if not ok[b]:
            rotation[b] = np.eye(3)
            translation[b] = 0.0
        source, target = _ratio_of(source_variances[b]), _ratio_of(target_variances[b])
        measure[b] = source if source < target or np.isnan(source) else target
    return ok, measure


@njit(cache=True)
def _ratio_of(variances: np.ndarray) -> float:
    """`_ratio` of one set's (3,) variances with numpy's operations: np.maximum keeps NaN and, on a tie, its
    second operand (max(-0, +0) is +0)."""
    if not variances[2] > 0:
        return 0.0
    second = variances[1] if variances[1] > 0.0 or np.isnan(variances[1]) else 0.0
    return np.sqrt(second / variances[2])


def conditioning(points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray | float:
    """sigma_2 / sigma_1 of the weighted, centred points: 0 when collinear, 1 when spread evenly in a plane.

    (P, 3) points give a float, (B, P, 3) points with (B, P) weights give B ratios. The rotation
    about a row of points is fixed only by their spread off the row, so its error grows as this
    ratio shrinks (tools/bench_conditioning.py measures how fast).
    """
    points = np.asarray(points, dtype=np.float64)
    weights = np.ones(points.shape[:-1]) if weights is None else np.asarray(weights, dtype=np.float64)
    total = weights.sum(axis=-1, keepdims=True)
    w = weights / np.where(total > 0, total, 1.0)
    centred = points - np.einsum("...p,...pi->...i", w, points)[..., None, :]
    ratio = _ratio(_variances(centred, w))
    return float(ratio) if ratio.ndim == 0 else ratio


def _variances(centred: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(..., 3) ascending principal variances of weighted, centred points (..., P, 3)."""
    return _eigvalsh(np.einsum("...p,...pi,...pj->...ij", w, centred, centred))


def _ratio(variances: np.ndarray) -> np.ndarray:
    """sqrt(second / largest principal variance) of (..., 3) variances; 0 where the points do not spread at all."""
    flat = np.ascontiguousarray(variances, np.float64).reshape(-1, 3)
    return _ratios(flat).reshape(variances.shape[:-1])


@njit(cache=True)
def _ratios(variances: np.ndarray) -> np.ndarray:
    """`_ratio_of` of each row of (M, 3) variances."""
    out = np.empty(len(variances))
    for m in range(len(variances)):
        out[m] = _ratio_of(variances[m])
    return out


@njit(cache=True)
def _spread_ok(variances: np.ndarray) -> bool:
    """Whether a weighted point set is not collinear: its second principal variance (of 3, ascending) is not ~0."""
    relative = _RELATIVE_VARIANCE * variances[2]
    return variances[1] > (relative if relative > _MIN_VARIANCE or np.isnan(relative) else _MIN_VARIANCE)


# The LAPACK gufuncs np.linalg.svd and eigvalsh call, the same results without the wrappers' checks
# and error-state context (for a 3 x 3 matrix those cost twice the decomposition; a query fits a dozen
# poses). A set that LAPACK cannot decompose (NaN input) gives NaN here rather than LinAlgError, and
# NaN variances fail `_spread_ok`: the set is flagged degenerate. The gufuncs are numpy's private API;
# where a numpy version has moved them, the public wrappers stand in (`_public_linalg`).
LinearAlgebra = tuple[Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]], Callable[[np.ndarray], np.ndarray]]


def _private_linalg() -> LinearAlgebra | None:
    """svd and eigvalsh (lower triangle) of stacked square matrices by numpy's own gufuncs; None
    where this numpy has none under these names (numpy 2's and numpy 1's)."""
    try:
        from numpy.linalg import _umath_linalg as gufuncs

        square_svd = getattr(gufuncs, "svd_f", None) or gufuncs.svd_n_f
        eigvalsh = gufuncs.eigvalsh_lo
    except (ImportError, AttributeError):
        return None
    return lambda m: square_svd(m, signature="d->ddd"), lambda m: eigvalsh(m, signature="d->d")


def _public_linalg() -> LinearAlgebra:
    """The same two by np.linalg's public functions, NaN for a matrix holding NaN or inf (where the
    wrappers would raise for the whole stack)."""

    def decomposed(function: Callable, matrices: np.ndarray):
        finite = np.isfinite(matrices).all(axis=(-2, -1))
        out = function(np.where(finite[..., None, None], matrices, 0.0))
        for part in out if isinstance(out, tuple) else (out,):
            part[~finite] = np.nan
        return out

    return lambda m: tuple(decomposed(np.linalg.svd, m)), lambda m: decomposed(np.linalg.eigvalsh, m)


_svd, _eigvalsh = _private_linalg() or _public_linalg()


def correspondence_weights(
    scores: np.ndarray, observed_axes: np.ndarray, landmark_axes: np.ndarray, mode: PoseWeights
) -> np.ndarray:
    """Per-correspondence weights `w = s_total * w_com` (or either factor alone, or ones).

    `s_total` is the similarity the matching used (negative values clipped to 0); the
    completeness `w_com = min(1, sqrt(|axes_obs|^2 / |axes_map|^2))` shrinks the weight of an
    object seen only in part, whose observed centre is biased. One pair at a time by `_weight`, the
    formula `weighted_sets` computes for the pipeline.
    """
    return _weights(np.ascontiguousarray(scores, np.float64), np.ascontiguousarray(observed_axes, np.float64),
                    np.ascontiguousarray(landmark_axes, np.float64), _WEIGHT_MODES[mode])


@njit(cache=True)
def _weights(scores, observed_axes, landmark_axes, mode):
    """`correspondence_weights` with the mode as a number (`_WEIGHT_MODES`)."""
    weights = np.empty(len(scores))
    for i in range(len(scores)):
        weights[i] = _weight(scores[i], observed_axes[i], landmark_axes[i], mode)
    return weights


_WEIGHT_MODES = {"none": 0, "sim": 1, "com": 2, "both": 3}


def weighted_sets(pairs: np.ndarray, scores: np.ndarray, counts: np.ndarray, pad: tuple[int, int, float],
                  observed: tuple[np.ndarray, np.ndarray], landmarks: tuple[np.ndarray, np.ndarray],
                  mode: PoseWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a batch fit of correspondence sets reads, in one compiled pass: (B, P, 3) observed and landmark
    centres and (B, P) `correspondence_weights` of B sets stacked one after another in `pairs` (M, 2) with
    their `scores` (M,), `counts[b]` pairs each, padded to the longest with the pair and score `pad` at weight
    0 (times its weight: numpy's `valid * weights`, the same bits). `observed`, `landmarks`: (centres, axes)."""
    return _weighted_sets(np.ascontiguousarray(pairs, np.int64), np.ascontiguousarray(scores, np.float64),
                          np.asarray(counts, np.int64), pad[0], pad[1], float(pad[2]), *observed, *landmarks,
                          _WEIGHT_MODES[mode])


@njit(cache=True)
def _weighted_sets(pairs, scores, counts, pad_observation, pad_landmark, pad_score, observed_centers, observed_axes,
                   landmark_centers, landmark_axes, mode):
    """`weighted_sets` with the mode as a number (`_WEIGHT_MODES`)."""
    width = counts.max() if len(counts) else 0
    source, target = np.empty((len(counts), width, 3)), np.empty((len(counts), width, 3))
    weights = np.empty((len(counts), width))
    start = 0
    for b in range(len(counts)):
        for p in range(width):
            valid = p < counts[b]
            k, n, score = ((pairs[start + p, 0], pairs[start + p, 1], scores[start + p]) if valid
                           else (pad_observation, pad_landmark, pad_score))
            source[b, p], target[b, p] = observed_centers[k], landmark_centers[n]
            weights[b, p] = (1.0 if valid else 0.0) * _weight(score, observed_axes[k], landmark_axes[n], mode)
        start += counts[b]
    return source, target, weights


@njit(cache=True)
def _weight(score, observed_axes, landmark_axes, mode):
    """One pair's `correspondence_weights`, numpy's operations in numpy's order: np.maximum and np.minimum
    (NaN kept, +0 over -0) and einsum's sum of three products, (x0 y0 + x2 y2) + x1 y1."""
    if mode == 0:
        return 1.0
    similarity = score if score > 0.0 or np.isnan(score) else 0.0
    if mode == 1:
        return similarity
    observed = (observed_axes[0] * observed_axes[0] + observed_axes[2] * observed_axes[2]) + observed_axes[1] * observed_axes[1]
    landmark = (landmark_axes[0] * landmark_axes[0] + landmark_axes[2] * landmark_axes[2]) + landmark_axes[1] * landmark_axes[1]
    ratio = np.sqrt(observed / (landmark if landmark > 1e-12 or np.isnan(landmark) else 1e-12))
    completeness = ratio if ratio < 1.0 or np.isnan(ratio) else 1.0
    return completeness if mode == 2 else similarity * completeness
