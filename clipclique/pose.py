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
from functools import cache

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import get_cython_function_address, intrinsic

from clipclique.config import PoseWeights
from clipclique.numpybits import fma, pairwise_sum
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
    rotation, translation, ok, _ = _fit(source, target, weights, conditioned=False)
    return rotation, translation, ok


def fit_rigid_conditioned(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_batch` and, per set, the smaller of the two sides' `conditioning`, both read off the
    same weighted covariances (a query's poses need both: measuring them apart doubled the work).

    One compiled pass per batch (`_fitted`: a query fits three or four batches, and the dozen numpy calls
    between the decompositions cost as much as they), to the bit as the passes around numpy's LAPACK
    gufuncs (`_fitted_by_gufuncs`), which still fit any set whose moments are not finite (LAPACK's answer
    to NaN and inf is the gufuncs' own) or that LAPACK could not decompose."""
    return _fit(source, target, weights, conditioned=True)


def _fit(source: np.ndarray, target: np.ndarray, weights: np.ndarray,
         conditioned: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_conditioned`; `conditioned` False: the measure is not wanted (NaN where not measured), and a
    set's spread is read off its covariances' eigenvalues only where `_surely_spread` cannot tell."""
    source, target = np.ascontiguousarray(source, np.float64), np.ascontiguousarray(target, np.float64)
    given = np.asarray(weights)
    if source.ndim != 3 or source.shape[2] != 3 or target.shape != source.shape or given.shape != source.shape[:2]:
        raise ValueError(f"source {source.shape}, target {target.shape} and weights {given.shape} must be (B, P, 3) "
                         "twice and (B, P)")  # the compiled pass reads them unchecked
    summed = given.dtype == np.float64 and given.flags.c_contiguous  # else numpy's sum of its own layout
    weights = np.ascontiguousarray(given, np.float64)
    total = np.zeros(0) if summed else np.asarray(given.sum(axis=1), np.float64)
    rotation, translation, ok, measure, decomposed = _fitted(weights, total, source, target, lapack_routines(),
                                                             conditioned)
    if not decomposed.all():
        rest = np.flatnonzero(~decomposed)
        rotation[rest], translation[rest], ok[rest], measure[rest] = _fitted_by_gufuncs(
            source[rest], target[rest], given[rest])
    return rotation, translation, ok, measure


@njit(cache=True)
def fit_rigid_sets(weights: np.ndarray, source: np.ndarray, target: np.ndarray,
                   lapack: tuple[int, int, int, int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_batch` of C-contiguous float64 (B, P) weights and (B, P, 3) points for compiled callers (a
    refinement fits inside one compiled call, clipclique.refine), and (B,) whether each set was fitted here:
    where one was not (its moments not finite, or LAPACK failed), only `fit_rigid_batch` has its bits (numpy's
    gufuncs). `lapack`: `lapack_routines()`."""
    rotation, translation, ok, _, decomposed = _fitted(weights, np.zeros(0), source, target, lapack, False)
    return rotation, translation, ok, decomposed


def _fitted_by_gufuncs(source: np.ndarray, target: np.ndarray,
                       weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`fit_rigid_conditioned` by compiled passes around numpy's LAPACK gufuncs: the SVD of the
    cross-covariances and one eigvalsh call for both sides'."""
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
def _fitted(weights: np.ndarray, total: np.ndarray, source: np.ndarray, target: np.ndarray,
            lapack: tuple[int, int, int, int, int],
            conditioned: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_fitted_by_gufuncs` in one pass, set by set, and (B,) whether each set was decomposed here (its moments
    finite and LAPACK content; the others are left to the gufuncs). `total`: the weights' sums, empty: summed
    here as numpy sums C-ordered rows (`numpybits.pairwise_sum`). `lapack`: `lapack_routines()`. `conditioned`: as
    `_fit`. u vt as numpy's matmul computes it (`_rotation_of`) and the translation as its einsum
    (`_translation_of`). The per-set helpers are inlined here (`inline="always"`): an array handed to a compiled
    call is counted in and out (two atomic operations), a few dozen a set."""
    count, points = weights.shape
    mean_source, mean_target = np.zeros((count, 3)), np.zeros((count, 3))
    cross, spreads = np.zeros((count, 3, 3)), np.zeros((2, count, 3, 3))
    w = np.empty(points)
    centred_source, centred_target = np.empty((points, 3)), np.empty((points, 3))
    rotation, translation = np.empty((count, 3, 3)), np.empty((count, 3))
    ok, measure, decomposed = np.zeros(count, np.bool_), np.zeros(count), np.zeros(count, np.bool_)
    flat = weights.reshape(-1)
    scratch = _workspace(lapack)
    u, vt = _svd_views(scratch)  # views made once, not per set: each is counted in and out
    source_spreads, target_spreads = spreads[0], spreads[1]
    turn, shift, source_variances, target_variances = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3)
    for b in range(count):
        summed = 0.0 + pairwise_sum(flat, b * points, (b + 1) * points, 0.0) if len(total) == 0 else total[b]
        _moments_of(b, weights, summed, source, target, mean_source, mean_target, cross, spreads, w,
                    centred_source, centred_target)
        if not _finite_at(b, mean_source, mean_target, cross, spreads):
            continue
        if _svd_of(lapack, scratch, cross, b):
            continue
        _proper_of(u, vt)
        _rotation_of(u, vt, turn)
        _translation_of(turn, mean_source, mean_target, b, shift)
        if not conditioned and _surely_spread(source_spreads, b) and _surely_spread(target_spreads, b):
            decomposed[b], ok[b], measure[b] = True, _kept(turn, shift, summed > 0), np.nan
        elif not (_eigvalsh_of(lapack, scratch, source_spreads, b, source_variances)
                  | _eigvalsh_of(lapack, scratch, target_spreads, b, target_variances)):
            decomposed[b] = True
            ok[b], measure[b] = _settle(turn, shift, summed, source_variances, target_variances)
        for i in range(3):  # copied out decomposed or not: where not, `_fit` puts the gufuncs' pose over it
            translation[b, i] = shift[i]
            for j in range(3):
                rotation[b, i, j] = turn[i, j]
    return rotation, translation, ok, measure, decomposed


@njit(cache=True, inline="always")
def _finite_at(b, mean_source, mean_target, cross, spreads) -> bool:
    """Whether set b's means, cross-covariance and both covariances are all finite: numpy's
    `np.isfinite(row).all()` of each, number by number (no row views or boolean arrays per set)."""
    for i in range(3):
        if not (np.isfinite(mean_source[b, i]) and np.isfinite(mean_target[b, i])):
            return False
        for j in range(3):
            if not (np.isfinite(cross[b, i, j]) and np.isfinite(spreads[0, b, i, j])
                    and np.isfinite(spreads[1, b, i, j])):
                return False
    return True


# LAPACK's dgesdd and dsyevd called from compiled code as numpy's gufuncs call them (np.linalg.svd: jobz "A";
# eigvalsh: jobz "N", the lower triangle; each with its queried optimal workspace), through scipy's LAPACK
# (numba's np.linalg uses the same, but queries and allocates the workspace on every 3 x 3 call: a third
# more than the decomposition). Their addresses are arguments, not constants, so the kernels stay cached.
_THREE, _SVD_WORK, _EIG_WORK, _EIG_INTS, _INFO = 0, 1, 2, 3, 4  # `_workspace`'s integers


@intrinsic
def _call(typingctx, address, pointers):
    """`void f(void *, ...)` at `address` called with the addresses in the tuple `pointers`."""
    count = len(pointers)

    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        function = builder.inttoptr(args[0], ir.FunctionType(ir.VoidType(), [pointer] * count).as_pointer())
        builder.call(function, [builder.inttoptr(value, pointer) for value in cgutils.unpack_tuple(builder, args[1])])
        return context.get_dummy_value()

    return types.void(address, pointers), codegen


@cache
def lapack_routines() -> tuple[int, int, int, int, int]:
    """dgesdd's and dsyevd's addresses and their optimal workspaces for a 3 x 3 matrix (`_workspace`'s sizes),
    asked once."""
    gesdd = get_cython_function_address("scipy.linalg.cython_lapack", "dgesdd")
    syevd = get_cython_function_address("scipy.linalg.cython_lapack", "dsyevd")
    return (gesdd, syevd, *_work_sizes(gesdd, syevd))


@njit(cache=True)
def _work_sizes(gesdd: int, syevd: int) -> tuple[int, int, int]:
    """LAPACK's optimal workspace sizes for a 3 x 3 matrix (its answer to a workspace of size -1): dgesdd's
    doubles, dsyevd's doubles and integers."""
    scratch = _workspace((gesdd, syevd, 1, 1, 1))
    integers, svd_work, eig_work, eig_integers = scratch[0], scratch[6], scratch[8], scratch[9]
    integers[_SVD_WORK:_INFO] = -1
    _svd_of((gesdd, syevd, 1, 1, 1), scratch, np.zeros((1, 3, 3)), 0)
    _eigvalsh_of((gesdd, syevd, 1, 1, 1), scratch, np.zeros((1, 3, 3)), 0, np.empty(3))
    return max(1, int(svd_work[0])), max(1, int(eig_work[0])), max(1, int(eig_integers[0]))


@njit(cache=True)
def _workspace(lapack):
    """The scratch `_svd_of` and `_eigvalsh_of` pass LAPACK: (integers: 3 and the workspaces' sizes, characters
    "ANL", a 3 x 3 matrix, u, vt and singular values, the SVD's work and integer work, eigvalsh's)."""
    integers = np.array([3, lapack[2], lapack[3], lapack[4], 0], np.int32)
    characters = np.array([ord("A"), ord("N"), ord("L")], np.uint8)
    return (integers, characters, np.empty(9), np.empty(9), np.empty(9), np.empty(3), np.empty(lapack[2]),
            np.empty(24, np.int32), np.empty(lapack[3]), np.empty(lapack[4], np.int32))  # dgesdd: 8 min(m, n) integers


@njit(cache=True, inline="always")
def _svd_of(lapack, scratch, matrices, b):
    """Whether LAPACK's dgesdd failed on the finite 3 x 3 `matrices[b]`; u and vt in the scratch (`_svd_views`),
    valid until the next call."""
    integers, characters, copy, u, vt, values, work, work_integers, _, _ = scratch
    _column_major(matrices, b, copy)
    integer = integers.ctypes.data  # the int32s' addresses by offset, not by slices (a view each, counted in and out)
    three = integer + 4 * _THREE
    _call(lapack[0], (characters.ctypes.data, three, three, copy.ctypes.data, three, values.ctypes.data,
                      u.ctypes.data, three, vt.ctypes.data, three, work.ctypes.data,
                      integer + 4 * _SVD_WORK, work_integers.ctypes.data, integer + 4 * _INFO))
    return integers[_INFO] != 0


@njit(cache=True, inline="always")
def _svd_views(scratch):
    """u and vt of the scratch's last SVD (`_svd_of`) as 3 x 3 views: LAPACK writes them column after column."""
    return scratch[3].reshape(3, 3).T, scratch[4].reshape(3, 3).T


@njit(cache=True, inline="always")
def _eigvalsh_of(lapack, scratch, matrices, b, values):
    """The ascending eigenvalues of the finite symmetric 3 x 3 `matrices[b]` (its lower triangle) by dsyevd into
    `values` (3,), and whether LAPACK failed."""
    integers, characters, copy, _, _, _, _, _, work, work_integers = scratch
    _column_major(matrices, b, copy)
    integer = integers.ctypes.data  # as `_svd_of`
    three = integer + 4 * _THREE
    _call(lapack[1], (characters.ctypes.data + 1, characters.ctypes.data + 2, three, copy.ctypes.data, three,
                      values.ctypes.data, work.ctypes.data, integer + 4 * _EIG_WORK, work_integers.ctypes.data,
                      integer + 4 * _EIG_INTS, integer + 4 * _INFO))
    return integers[_INFO] != 0


@njit(cache=True, inline="always")
def _column_major(matrices: np.ndarray, b: int, out: np.ndarray) -> None:
    """The 3 x 3 `matrices[b]` into `out` (9,) column after column, as LAPACK reads it (the call overwrites it)."""
    for i in range(3):
        for j in range(3):
            out[i + 3 * j] = matrices[b, i, j]


@njit(cache=True, inline="always")
def _rotation_of(u: np.ndarray, vt: np.ndarray, out: np.ndarray) -> None:
    """u @ vt of 3 x 3 matrices into `out` as numpy's matmul computes it (a dgemm per matrix of a stack, in
    OpenBLAS: from +0, one fused multiply-add per k in order)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = fma(u[i, 2], vt[2, j], fma(u[i, 1], vt[1, j], fma(u[i, 0], vt[0, j], 0.0)))


@njit(cache=True, inline="always")
def _translation_of(rotation: np.ndarray, mean_source: np.ndarray, mean_target: np.ndarray, b: int,
                    out: np.ndarray) -> None:
    """mean_target[b] - rotation @ mean_source[b] into `out` as `mean_target - np.einsum("bij,bj->bi", ...)` does:
    einsum's sum of three products, (x0 y0 + x2 y2) + x1 y1, added to its 0."""
    for i in range(3):
        product = ((rotation[i, 0] * mean_source[b, 0] + rotation[i, 2] * mean_source[b, 2])
                   + rotation[i, 1] * mean_source[b, 1])
        out[i] = mean_target[b, i] - (0.0 + product)


@njit(cache=True)
def _moments(weights: np.ndarray, total: np.ndarray, source: np.ndarray,
             target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per set b, with w = weights / total (1 where the total is not positive): the weighted means of
    source and target, the cross-covariance sum_p w_p t_p s_p^T and (2, B, 3, 3) either side's covariance
    (source first), of the centred points (`_moments_of`)."""
    count, points = weights.shape
    mean_source, mean_target = np.zeros((count, 3)), np.zeros((count, 3))
    cross, spreads = np.zeros((count, 3, 3)), np.zeros((2, count, 3, 3))
    w = np.empty(points)
    centred_source, centred_target = np.empty((points, 3)), np.empty((points, 3))
    for b in range(count):
        _moments_of(b, weights, total[b], source, target, mean_source, mean_target, cross, spreads, w,
                    centred_source, centred_target)
    return mean_source, mean_target, cross, spreads


@njit(cache=True, inline="always")
def _moments_of(b, weights, total, source, target, mean_source, mean_target, cross, spreads, w, centred_source,
                centred_target) -> None:
    """`_moments` of set b into row b of the zeroed outputs (w, centred_*: scratch). Each sum adds its terms in
    order from 0, each term (w_p * x_i) * y_j, as `np.einsum("bp,bpi,bpj->bij", ...)` does: the same bits in one
    call instead of a dozen."""
    points = weights.shape[1]
    safe = total if total > 0 else 1.0
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


@njit(cache=True)
def _proper(u: np.ndarray, vt: np.ndarray) -> None:
    """`_proper_of` of each of a stack's u and vt, in place."""
    for b in range(len(u)):
        _proper_of(u[b], vt[b])


@njit(cache=True, inline="always")
def _proper_of(u: np.ndarray, vt: np.ndarray) -> None:
    """In place, u's third column negated where u vt is a reflection, so that u vt is a rotation: what
    `u[:, :, 2] *= np.where(sign == 0, 1, sign)` with `sign = np.sign(np.linalg.det(u @ vt))` does, without the
    product and LAPACK's determinant. The SVD's u and vt are orthogonal, so det(u) det(vt) and det(u vt) are both
    +-1 to within round-off and never 0: the same sign, and NaN alike where the SVD gave NaN (then the sets'
    covariances are not finite either, and `_settled` replaces the rotation)."""
    sign = np.sign(_det3(u) * _det3(vt))
    factor = 1.0 if sign == 0 else sign
    for i in range(3):
        u[i, 2] *= factor


@njit(cache=True, inline="always")
def _det3(m: np.ndarray) -> float:
    """A 3 x 3 determinant by cofactors (its sign is what `_proper` reads)."""
    return (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]) - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
            + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))


@njit(cache=True)
def _settled(rotation: np.ndarray, translation: np.ndarray, total: np.ndarray, source_variances: np.ndarray,
             target_variances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B,) `_settle` of each set."""
    ok, measure = np.empty(len(total), np.bool_), np.empty(len(total))
    for b in range(len(total)):
        ok[b], measure[b] = _settle(rotation[b], translation[b], total[b], source_variances[b], target_variances[b])
    return ok, measure


@njit(cache=True, inline="always")
def _settle(rotation: np.ndarray, translation: np.ndarray, total: float, source_variances: np.ndarray,
            target_variances: np.ndarray) -> tuple[bool, float]:
    """Whether a set fixes a pose (positive weights, neither side collinear), and the smaller of the two sides'
    `_ratio`, np.minimum's way; a set that fixes none gets the identity, in place."""
    ok = _kept(rotation, translation, total > 0 and _spread_ok(source_variances) and _spread_ok(target_variances))
    source, target = _ratio_of(source_variances), _ratio_of(target_variances)
    return ok, source if source < target or np.isnan(source) else target


@njit(cache=True, inline="always")
def _kept(rotation: np.ndarray, translation: np.ndarray, ok: bool) -> bool:
    """`ok`, the pose replaced by the identity, in place, where it is not."""
    if not ok:
        rotation[:] = np.eye(3)
        translation[:] = 0.0
    return ok


@njit(cache=True, inline="always")
def _surely_spread(covariances: np.ndarray, b: int) -> bool:
    """True only where `_spread_ok` of LAPACK's eigenvalues of the finite symmetric 3 x 3 `covariances[b]` (its lower
    triangle, as dsyevd reads it) is surely True, told without them: its middle eigenvalue is at least the
    smaller one of each 2 x 2 principal submatrix (Cauchy's interlacing), computed here within 12 eps of its
    Frobenius norm F, and dsyevd's eigenvalues lie within 1e-10 F of the exact ones (it is backward stable:
    within a few hundred eps of F for a 3 x 3 matrix). So the middle eigenvalue LAPACK gives exceeds 0.8e-9 F,
    above either of `_spread_ok`'s thresholds (1e-12 or 1e-12 of the largest, at most F + 1e-10 F). Where this
    says False (a row of points, a set too small to tell), the eigenvalues decide."""
    m = covariances
    norm = np.sqrt(m[b, 0, 0] * m[b, 0, 0] + m[b, 1, 1] * m[b, 1, 1] + m[b, 2, 2] * m[b, 2, 2]
                   + 2.0 * (m[b, 1, 0] * m[b, 1, 0] + m[b, 2, 0] * m[b, 2, 0] + m[b, 2, 1] * m[b, 2, 1]))
    middle_at_least = -np.inf
    for i, j in ((0, 1), (0, 2), (1, 2)):
        a, d, off = m[b, i, i], m[b, j, j], m[b, j, i]
        half = 0.5 * (a - d)
        middle_at_least = max(middle_at_least, 0.5 * (a + d) - np.sqrt(half * half + off * off))
    return middle_at_least > 1e-9 * norm + 2e-12


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
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
    """(B,) how many of each row of (B, P) weights are not 0 (NaN counts): `np.count_nonzero(weights, axis=1)`,
    which with an axis converts the whole array to bool and sums it (ten times the work of a batch's count)."""
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
    0 (times its weight: numpy's `valid * weights`, the same bits). `observed`, `landmarks`: (centres, axes)."""
    return compiled_weighted_sets(np.ascontiguousarray(pairs, np.int64), np.ascontiguousarray(scores, np.float64),
                                  np.asarray(counts, np.int64), pad[0], pad[1], float(pad[2]), *observed, *landmarks,
                                  WEIGHT_MODES[mode])


@njit(cache=True)
def compiled_weighted_sets(pairs, scores, counts, pad_observation, pad_landmark, pad_score, observed_centers,
                           observed_axes, landmark_centers, landmark_axes, mode):
    """`weighted_sets` with the mode as a number (`WEIGHT_MODES`), for compiled callers too (clipclique.refine)."""
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
            weights[b, p] = (1.0 if valid else 0.0) * _weight(score, observed_axes, k, landmark_axes, n, mode)
        start += counts[b]
    return source, target, weights


@njit(cache=True, inline="always")
def _weight(score, observed_axes, k, landmark_axes, n, mode):
    """One pair's `correspondence_weights` (observation k's axes, landmark n's: indices, not row views), numpy's
    operations in numpy's order: np.maximum and np.minimum (NaN kept, +0 over -0) and einsum's sum of three
    products, (x0 y0 + x2 y2) + x1 y1."""
    if mode == 0:
        return 1.0
    similarity = score if score > 0.0 or np.isnan(score) else 0.0
    if mode == 1:
        return similarity
    observed = ((observed_axes[k, 0] * observed_axes[k, 0] + observed_axes[k, 2] * observed_axes[k, 2])
                + observed_axes[k, 1] * observed_axes[k, 1])
    landmark = ((landmark_axes[n, 0] * landmark_axes[n, 0] + landmark_axes[n, 2] * landmark_axes[n, 2])
                + landmark_axes[n, 1] * landmark_axes[n, 1])
    ratio = np.sqrt(observed / (landmark if landmark > 1e-12 or np.isnan(landmark) else 1e-12))
    completeness = ratio if ratio < 1.0 or np.isnan(ratio) else 1.0
    return completeness if mode == 2 else similarity * completeness
