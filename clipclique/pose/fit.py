"""Weighted closed-form rigid alignment (Kabsch/Umeyama without scale), Umeyama with scale, and the weights.

Given camera-frame observation centres `p_i`, map landmark centres `q_i` and weights `w_i >= 0`,
the pose minimizes `sum_i w_i |R p_i + t - q_i|^2`: weighted centroids, and the rotation of the
weighted cross-covariance by Horn's unit quaternion (`det R = +1`, never a reflection). Inputs that cannot
fix a 6-DoF pose (fewer than 3 points, collinear points, zero weights) raise `DegeneratePoseError`
with the reason; the solver never returns NaN.
"""

from __future__ import annotations

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

    `ok` is False where a set is degenerate (collinear, weights summing to zero, not finite); those rows
    hold the identity so that callers can mask them without meeting NaN.
    """
    weights = np.ones(np.shape(source)[:2]) if weights is None else weights
    return fit_rigid_conditioned(source, target, weights)[:3]


def fit_rigid_conditioned(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_batch` and, per set, the smaller of the two sides' `conditioning` (0 where a set is not
    finite or its weights do not sum to a positive number), both from one compiled pass over the batch."""
    source, target = np.ascontiguousarray(source, np.float64), np.ascontiguousarray(target, np.float64)
    weights = np.asarray(weights)
    if source.ndim != 3 or source.shape[2] != 3 or target.shape != source.shape or weights.shape != source.shape[:2]:
        raise ValueError(f"source {source.shape}, target {target.shape} and weights {weights.shape} must be "
                         "(B, P, 3) twice and (B, P)")  # the compiled pass reads them unchecked
    return _fit(np.ascontiguousarray(weights, np.float64), source, target, True)


@njit(cache=True)
def fit_rigid_sets(weights: np.ndarray, source: np.ndarray,
                   target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_batch` of C-contiguous float64 (B, P) weights and (B, P, 3) points for compiled callers (a
    refinement fits inside one compiled call, clipclique.pose.refine), without the conditioning: a set of
    non-negative weights whose spread passes for certain (`_surely_spread`) skips the eigenvalues (a third of
    its fit), with the same pose and ok."""
    rotation, translation, ok, _ = _fit(weights, source, target, False)
    return rotation, translation, ok


@njit(cache=True)
def _fit(weights: np.ndarray, source: np.ndarray, target: np.ndarray,
         conditioned: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_conditioned` of checked, C-contiguous float64 arrays, set by set (`_fit_set`): a query fits a
    few batches of a few dozen sets each, so one compiled call per batch rather than a dozen numpy calls.
    `conditioned` False: the conditioning is not wanted (0 where the eigenvalues were skipped)."""
    count = len(weights)
    rotation, translation = np.empty((count, 3, 3)), np.empty((count, 3))
    ok, measure = np.zeros(count, np.bool_), np.zeros(count)
    moments, scratch = np.empty((3, 3, 3)), np.empty((2, 4, 4))
    for b in range(count):
        ok[b], measure[b] = _fit_set(weights, source, target, b, moments, scratch, rotation, translation,
                                     conditioned)
    return rotation, translation, ok, measure


@njit(cache=True, inline="always")
def _fit_set(weights, source, target, b, moments, scratch, rotation, translation, conditioned) -> tuple[bool, float]:
    """Set b's pose into rotation[b] and translation[b], whether it fixes one, and its conditioning.

    The weighted means, the cross-covariance and both sides' covariances (`moments`: cross, source, target),
    the covariances' eigenvalues (`_eigenvalues`) for the spread test and the conditioning, and the rotation
    by Horn's quaternion (`_rotation`). A set that fixes no pose gets the identity. Not `conditioned`: the
    eigenvalues only where `_surely_spread` does not settle the spread test (conditioning 0 otherwise).
    Inlined: an array passed to a compiled call is reference-counted, a few dozen times a set."""
    total, means = _moments(weights, source, target, b, moments)
    fitted, measure = False, 0.0
    if total > 0 and _finite(means, moments):
        if not conditioned and _nonnegative(weights, b) and _surely_spread(moments[1]) and _surely_spread(moments[2]):
            fitted = True
        else:
            source_variances = _eigenvalues(moments[1], scratch[0])
            target_variances = _eigenvalues(moments[2], scratch[0])
            fitted = _spread_ok(source_variances) and _spread_ok(target_variances)
            measure = min(_ratio_of(source_variances), _ratio_of(target_variances))
    if fitted:
        _rotation(moments[0], scratch, rotation, b)
        for i in range(3):
            translation[b, i] = means[1][i] - (rotation[b, i, 0] * means[0][0] + rotation[b, i, 1] * means[0][1]
                                               + rotation[b, i, 2] * means[0][2])
    else:
        for i in range(3):
            translation[b, i] = 0.0
            for j in range(3):
                rotation[b, i, j] = 1.0 if i == j else 0.0
    return fitted, measure


@njit(cache=True, inline="always")
def _nonnegative(weights, b) -> bool:
    """Whether set b's weights are all >= 0 (its covariances then sums of outer products, positive semidefinite)."""
    for p in range(weights.shape[1]):
        if not weights[b, p] >= 0.0:
            return False
    return True


@njit(cache=True, inline="always")
def _surely_spread(m: np.ndarray) -> bool:
    """Whether the positive semidefinite covariance `m` passes `_spread_ok` whatever its eigenvalues' last digits,
    from its trace and its principal 2 x 2 minors' sum c2 alone: with eigenvalues l1 <= l2 <= l3 >= 0, l3 <= trace
    and c2 = l1 l2 + l1 l3 + l2 l3 <= 3 l2 l3, so l2 >= c2 / (3 trace); asked to clear the test's threshold a
    thousandfold, rounding cannot move it across. A set of objects over a room clears it by orders of magnitude,
    and a thin or tiny one is left to the eigenvalues."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    minors = m[0, 0] * m[1, 1] - m[0, 1] * m[0, 1] + m[0, 0] * m[2, 2] - m[0, 2] * m[0, 2] + m[1, 1] * m[2, 2] \
        - m[1, 2] * m[1, 2]
    return minors > 3e3 * trace * max(_RELATIVE_VARIANCE * trace, _MIN_VARIANCE)


@njit(cache=True, inline="always")
def _moments(weights, source, target, b, moments):
    """Set b's total weight, its weighted means ((3,) source, (3,) target) and, into `moments` (3, 3, 3), the
    cross-covariance sum_p w_p s_p t_p^T (source index first) and both sides' covariances, w = weights / total.
    The covariances are of the centred points (two passes): one pass of raw sums would lose their digits to
    cancellation where the points lie far from the origin."""
    points = weights.shape[1]
    total = 0.0
    for p in range(points):
        total += weights[b, p]
    scale = 1.0 / total if total > 0 else 0.0
    ms, mt = np.zeros(3), np.zeros(3)
    for p in range(points):
        for i in range(3):
            ms[i] += weights[b, p] * source[b, p, i]
            mt[i] += weights[b, p] * target[b, p, i]
    for i in range(3):
        ms[i] *= scale
        mt[i] *= scale
    moments[:] = 0.0
    for p in range(points):
        w = weights[b, p] * scale
        s0, s1, s2 = source[b, p, 0] - ms[0], source[b, p, 1] - ms[1], source[b, p, 2] - ms[2]
        t0, t1, t2 = target[b, p, 0] - mt[0], target[b, p, 1] - mt[1], target[b, p, 2] - mt[2]
        ws0, ws1, ws2, wt0, wt1, wt2 = w * s0, w * s1, w * s2, w * t0, w * t1, w * t2
        moments[0, 0, 0] += ws0 * t0
        moments[0, 0, 1] += ws0 * t1
        moments[0, 0, 2] += ws0 * t2
        moments[0, 1, 0] += ws1 * t0
        moments[0, 1, 1] += ws1 * t1
        moments[0, 1, 2] += ws1 * t2
        moments[0, 2, 0] += ws2 * t0
        moments[0, 2, 1] += ws2 * t1
        moments[0, 2, 2] += ws2 * t2
        moments[1, 0, 0] += ws0 * s0
        moments[1, 0, 1] += ws0 * s1
        moments[1, 0, 2] += ws0 * s2
        moments[1, 1, 1] += ws1 * s1
        moments[1, 1, 2] += ws1 * s2
        moments[1, 2, 2] += ws2 * s2
        moments[2, 0, 0] += wt0 * t0
        moments[2, 0, 1] += wt0 * t1
        moments[2, 0, 2] += wt0 * t2
        moments[2, 1, 1] += wt1 * t1
        moments[2, 1, 2] += wt1 * t2
        moments[2, 2, 2] += wt2 * t2
    for k in (1, 2):  # the covariances' lower triangles mirror the upper
        moments[k, 1, 0], moments[k, 2, 0], moments[k, 2, 1] = moments[k, 0, 1], moments[k, 0, 2], moments[k, 1, 2]
    return total, (ms, mt)


@njit(cache=True, inline="always")
def _finite(means, moments) -> bool:
    """Whether the means and every moment are finite (NaN or inf in a set, or moments that overflow)."""
    for i in range(3):
        if not (np.isfinite(means[0][i]) and np.isfinite(means[1][i])):
            return False
    for k in range(3):
        for i in range(3):
            for j in range(3):
                if not np.isfinite(moments[k, i, j]):
                    return False
    return True


@njit(cache=True, inline="always")
def _eigenvalues(m: np.ndarray, a: np.ndarray) -> tuple[float, float, float]:
    """The ascending eigenvalues of the finite symmetric 3 x 3 `m` (`_diagonalize`; `a` (4, 4): scratch). Not
    Smith's closed form: there the two eigenvalues of a tie split by sqrt(eps) |m|, so that a row of points
    (two zero variances) would seem spread a hundred-millionth of its length across, ten thousand times the
    spread test's threshold."""
    for i in range(3):
        for j in range(3):
            a[i, j] = m[i, j]
    _diagonalize(a, a, 3, False)
    low, middle, high = a[0, 0], a[1, 1], a[2, 2]
    low, middle = min(low, middle), max(low, middle)
    middle, high = min(middle, high), max(middle, high)
    return min(low, middle), max(low, middle), high


@njit(cache=True, inline="always")
def _rotation(cross: np.ndarray, scratch: np.ndarray, rotation: np.ndarray, b: int) -> None:
    """The rotation R maximizing trace(R `cross`) (cross: sum_p w_p s_p t_p^T), into rotation[b], by Horn's
    quaternion (1987): the unit eigenvector q of the largest eigenvalue of a symmetric 4 x 4 matrix N of `cross`
    (`_top_eigenvector`), and R = R(q), a rotation whatever the data (never a reflection). N's two largest
    eigenvalues differ by twice the sum of cross's two smaller singular values (their sum with the sign of its
    determinant): small for a thin set, and then only an eigen-solver accurate to eps |N| tells them apart (the
    largest root of N's characteristic polynomial, as Theobald's QCP finds it, is only accurate to eps |N| over
    that difference, and a set a thousandth as wide as long rotated wrongly by up to half a turn)."""
    m = cross
    sxx, sxy, sxz, syx, syy, syz, szx, szy, szz = (m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0],
                                                   m[2, 1], m[2, 2])
    n = scratch[0]
    n[0, 0], n[1, 1], n[2, 2], n[3, 3] = sxx + syy + szz, sxx - syy - szz, syy - sxx - szz, szz - sxx - syy
    n[0, 1] = n[1, 0] = syz - szy
    n[0, 2] = n[2, 0] = szx - sxz
    n[0, 3] = n[3, 0] = sxy - syx
    n[1, 2] = n[2, 1] = sxy + syx
    n[1, 3] = n[3, 1] = szx + sxz
    n[2, 3] = n[3, 2] = syz + szy
    _quaternion_rotation(_top_eigenvector(n, scratch[1]), rotation, b)


@njit(cache=True, inline="always")
def _top_eigenvector(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The unit eigenvector of the largest eigenvalue of the symmetric 4 x 4 `a` (overwritten; `v` (4, 4):
    scratch) by `_diagonalize`; of a tie of the largest (the rotation is not unique) the first, as good as any."""
    _diagonalize(a, v, 4, True)
    best = 0
    for i in range(1, 4):
        if a[i, i] > a[best, best]:
            best = i
    return v[:, best]


@njit(cache=True, inline="always")
def _diagonalize(a: np.ndarray, v: np.ndarray, size: int, vectors: bool) -> None:
    """The symmetric `size` x `size` top left of `a` diagonalized in place by cyclic Jacobi rotations and, where
    `vectors`, their product into `v` (its columns the eigenvectors). Backward stable: each eigenvalue within a
    few eps of |a| and each eigenvector within that over its gap to the others, whatever their multiplicity.
    Three or four sweeps of size (size - 1) / 2 rotations."""
    total = 0.0
    for i in range(size):
        for j in range(size):
            total += a[i, j] * a[i, j]
            if vectors:
                v[i, j] = 1.0 if i == j else 0.0
    for _ in range(30):
        off = 0.0
        for i in range(size - 1):
            for j in range(i + 1, size):
                off += a[i, j] * a[i, j]
        if not off > 1e-34 * total:
            return
        for p in range(size - 1):
            for q in range(p + 1, size):
                if a[p, q] != 0.0:
                    _jacobi_rotation(a, v, p, q, size, vectors)


@njit(cache=True, inline="always")
def _jacobi_rotation(a: np.ndarray, v: np.ndarray, p: int, q: int, size: int, vectors: bool) -> None:
    """The plane rotation that zeroes a[p, q] applied to both sides of the symmetric `a` (its top left `size`),
    and to `v`'s columns where `vectors`: t = tan of the angle, the smaller root of t^2 + 2 theta t - 1 = 0."""
    theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
    t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0)) if abs(theta) < 1e150 else 0.5 / abs(theta)
    t = -t if theta < 0.0 else t
    c = 1.0 / np.sqrt(t * t + 1.0)
    s = t * c
    apq = a[p, q]
    a[p, p] -= t * apq
    a[q, q] += t * apq
    a[p, q] = a[q, p] = 0.0
    for r in range(size):
        if r != p and r != q:
            g, h = a[r, p], a[r, q]
            a[r, p] = a[p, r] = c * g - s * h
            a[r, q] = a[q, r] = s * g + c * h
    if vectors:
        for r in range(size):
            g, h = v[r, p], v[r, q]
            v[r, p] = c * g - s * h
            v[r, q] = s * g + c * h


@njit(cache=True, inline="always")
def _quaternion_rotation(q: np.ndarray, rotation: np.ndarray, b: int) -> None:
    """The rotation matrix of the unit quaternion q = (w, x, y, z) into rotation[b]."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    rotation[b, 0, 0] = w * w + x * x - y * y - z * z
    rotation[b, 0, 1] = 2.0 * (x * y - w * z)
    rotation[b, 0, 2] = 2.0 * (x * z + w * y)
    rotation[b, 1, 0] = 2.0 * (x * y + w * z)
    rotation[b, 1, 1] = w * w - x * x + y * y - z * z
    rotation[b, 1, 2] = 2.0 * (y * z - w * x)
    rotation[b, 2, 0] = 2.0 * (x * z - w * y)
    rotation[b, 2, 1] = 2.0 * (y * z + w * x)
    rotation[b, 2, 2] = w * w - x * x - y * y + z * z


@njit(cache=True, inline="always")
def _spread_ok(variances: tuple[float, float, float]) -> bool:
    """Whether a weighted point set is not collinear: its second principal variance (of 3, ascending) is not ~0."""
    return variances[1] > max(_RELATIVE_VARIANCE * variances[2], _MIN_VARIANCE)


@njit(cache=True, inline="always")
def _ratio_of(variances: tuple[float, float, float]) -> float:
    """sqrt(second / largest principal variance) of ascending variances; 0 where they do not spread at all."""
    if not variances[2] > 0.0:
        return 0.0
    return np.sqrt(max(variances[1], 0.0) / variances[2])


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
    covariances = np.einsum("...p,...pi,...pj->...ij", w, centred, centred)
    ratio = _ratios(np.ascontiguousarray(covariances.reshape(-1, 3, 3))).reshape(covariances.shape[:-2])
    return float(ratio) if ratio.ndim == 0 else ratio


@njit(cache=True)
def _ratios(covariances: np.ndarray) -> np.ndarray:
    """`_ratio_of` of the eigenvalues of each of (M, 3, 3) covariances (0 where one is not finite)."""
    out, scratch = np.zeros(len(covariances)), np.empty((4, 4))
    for k in range(len(covariances)):
        if np.isfinite(covariances[k]).all():
            out[k] = _ratio_of(_eigenvalues(covariances[k], scratch))
    return out


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
                    np.ascontiguousarray(landmark_axes, np.float64), WEIGHT_MODES[mode])


@njit(cache=True)
def _weights(scores, observed_axes, landmark_axes, mode):
    """`correspondence_weights` with the mode as a number (`WEIGHT_MODES`)."""
    weights = np.empty(len(scores))
    for i in range(len(scores)):
        weights[i] = _weight(scores[i], observed_axes, i, landmark_axes, i, mode)
    return weights


WEIGHT_MODES = {"none": 0, "sim": 1, "com": 2, "both": 3}


@njit(cache=True)
def nonzero_counts(weights: np.ndarray) -> np.ndarray:
    """(B,) how many of each row of (B, P) weights are not 0 (NaN counts): `np.count_nonzero(weights, axis=1)`
    without converting the whole array to bool first (ten times the work of a batch's count)."""
    counts = np.zeros(len(weights), np.int64)
    for b in range(len(weights)):
        for p in range(weights.shape[1]):
            counts[b] += weights[b, p] != 0
    return counts


def weighted_sets(pairs: np.ndarray, scores: np.ndarray, counts: np.ndarray, pad: tuple[int, int, float],
                  observed: tuple[np.ndarray, np.ndarray], landmarks: tuple[np.ndarray, np.ndarray],
                  mode: PoseWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a batch fit of correspondence sets reads, in one compiled pass: (B, P, 3) observed and landmark
    centres and (B, P) `correspondence_weights` of B sets stacked one after another in `pairs` (M, 2) with
    their `scores` (M,), `counts[b]` pairs each, padded to the longest with the pair and score `pad` at weight
    0. `observed`, `landmarks`: (centres, axes)."""
    return compiled_weighted_sets(np.ascontiguousarray(pairs, np.int64), np.ascontiguousarray(scores, np.float64),
                                  np.asarray(counts, np.int64), pad[0], pad[1], float(pad[2]), *observed, *landmarks,
                                  WEIGHT_MODES[mode])


def fit_sets(pairs: np.ndarray, scores: np.ndarray, counts: np.ndarray, pad: tuple[int, int, float],
             observed: tuple[np.ndarray, np.ndarray], landmarks: tuple[np.ndarray, np.ndarray], mode: PoseWeights,
             min_conditioning: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """`fit_rigid_conditioned` of `weighted_sets(pairs, scores, counts, pad, observed, landmarks, mode)` in one
    compiled call, with `ok` also False where fewer than 3 pairs weigh (not 0) or the conditioning is below
    `min_conditioning` (a near-row of objects); and whether every set is ok. The clique poses' fits: the three
    calls it replaces, their argument checks and the batch arrays handed back and forth cost a small query more
    than its fits."""
    return _fit_sets(np.asarray(pairs, np.int64), np.asarray(scores, np.float64), np.asarray(counts, np.int64),
                     pad[0], pad[1], float(pad[2]), *observed, *landmarks, WEIGHT_MODES[mode], float(min_conditioning))


@njit(cache=True)
def _fit_sets(pairs, scores, counts, pad_observation, pad_landmark, pad_score, observed_centers, observed_axes,
              landmark_centers, landmark_axes, mode, min_conditioning):
    source, target, weights = compiled_weighted_sets(pairs, scores, counts, pad_observation, pad_landmark, pad_score,
                                                     observed_centers, observed_axes, landmark_centers, landmark_axes,
                                                     mode)
    rotation, translation, ok, measure = _fit(weights, source, target, True)
    usable = True
    for b in range(len(ok)):
        weighed = 0
        for p in range(weights.shape[1]):
            weighed += weights[b, p] != 0  # NaN counts, as in nonzero_counts
        ok[b] = ok[b] and weighed >= 3 and measure[b] >= min_conditioning
        usable &= ok[b]
    return rotation, translation, ok, measure, usable


@njit(cache=True)
def compiled_weighted_sets(pairs, scores, counts, pad_observation, pad_landmark, pad_score, observed_centers,
                           observed_axes, landmark_centers, landmark_axes, mode):
    """`weighted_sets` with the mode as a number (`WEIGHT_MODES`), for compiled callers too (clipclique.pose.refine)."""
    width = counts.max() if len(counts) else 0
    source, target = np.empty((len(counts), width, 3)), np.empty((len(counts), width, 3))
    weights = np.empty((len(counts), width))
    start = 0
    for b in range(len(counts)):
        for p in range(width):
            valid = p < counts[b]
            k, n, score = ((pairs[start + p, 0], pairs[start + p, 1], scores[start + p]) if valid
                           else (pad_observation, pad_landmark, pad_score))
            for i in range(3):  # number by number: a row is a view, counted in and out
                source[b, p, i], target[b, p, i] = observed_centers[k, i], landmark_centers[n, i]
            weights[b, p] = _weight(score, observed_axes, k, landmark_axes, n, mode) if valid else 0.0
        start += counts[b]
    return source, target, weights


@njit(cache=True, inline="always")
def _weight(score, observed_axes, k, landmark_axes, n, mode):
    """One pair's `correspondence_weights` (observation k's axes, landmark n's: indices, not row views); a NaN
    score stays NaN (a bad score is not silently a zero weight)."""
    if mode == 0:
        return 1.0
    similarity = score if score > 0.0 or np.isnan(score) else 0.0
    if mode == 1:
        return similarity
    observed = (observed_axes[k, 0] * observed_axes[k, 0] + observed_axes[k, 1] * observed_axes[k, 1]
                + observed_axes[k, 2] * observed_axes[k, 2])
    landmark = (landmark_axes[n, 0] * landmark_axes[n, 0] + landmark_axes[n, 1] * landmark_axes[n, 1]
                + landmark_axes[n, 2] * landmark_axes[n, 2])
    ratio = np.sqrt(observed / (landmark if landmark > 1e-12 or np.isnan(landmark) else 1e-12))
    completeness = ratio if ratio < 1.0 or np.isnan(ratio) else 1.0
    return completeness if mode == 2 else similarity * completeness
