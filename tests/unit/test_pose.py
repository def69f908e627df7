import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.geometry import random_rotation
from clipclique.pose import (MIN_SPREAD_M, RELATIVE_SPREAD, DegeneratePoseError, correspondence_weights, fit_rigid,
                             fit_rigid_batch, fit_rigid_conditioned, fit_rigid_sets, fit_similarity, lapack_routines,
                             nonzero_counts, weighted_sets)


@pytest.mark.parametrize("seed", range(5))
def test_weighted_pose_equals_scipy_align_vectors(seed):
    rng = np.random.default_rng(seed)
    source = rng.normal(size=(12, 3))
    rotation = random_rotation(rng)
    target = source @ rotation.T + rng.normal(size=3) + rng.normal(scale=0.2, size=(12, 3))
    weights = rng.uniform(0.1, 2.0, 12)

    pose = fit_rigid(source, target, weights)

    mean_source = weights @ source / weights.sum()
    mean_target = weights @ target / weights.sum()
    expected, _ = Rotation.align_vectors(target - mean_target, source - mean_source, weights=weights)
    np.testing.assert_allclose(pose.rotation, expected.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(pose.translation, mean_target - expected.as_matrix() @ mean_source, atol=1e-9)


def test_exact_correspondences_give_the_exact_pose():
    rng = np.random.default_rng(7)
    source = rng.normal(size=(5, 3))
    rotation, translation = random_rotation(rng), np.array([1.0, -2.0, 0.5])
    pose = fit_rigid(source, source @ rotation.T + translation)
    np.testing.assert_allclose(pose.rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(pose.translation, translation, atol=1e-12)


def test_mirrored_points_still_give_a_rotation():
    rng = np.random.default_rng(3)
    source = rng.normal(size=(6, 3))
    pose = fit_rigid(source, source * np.array([1.0, 1.0, -1.0]))
    assert np.linalg.det(pose.rotation) == pytest.approx(1.0)


def test_zero_weights_drop_their_points():
    rng = np.random.default_rng(4)
    source = rng.normal(size=(6, 3))
    rotation = random_rotation(rng)
    target = source @ rotation.T
    target[5] += 10.0  # an outlier with weight 0 must not move the pose
    pose = fit_rigid(source, target, np.array([1, 1, 1, 1, 1, 0.0]))
    np.testing.assert_allclose(pose.rotation, rotation, atol=1e-12)


@pytest.mark.parametrize(
    ("source", "weights", "reason"),
    [
        (np.eye(3)[:2], None, "fewer than 3 correspondences"),
        (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3.0]]), None, "collinear"),
        (np.eye(3), np.zeros(3), "positive weight"),
        (np.eye(4)[:, :3], np.array([1.0, 1.0, 0.0, 0.0]), "positive weight"),
        (np.eye(3), np.array([1.0, np.nan, 1.0]), "finite"),
    ],
)
def test_degenerate_input_is_an_explicit_failure(source, weights, reason):
    with pytest.raises(DegeneratePoseError, match=reason):
        fit_rigid(source, source + 1.0, weights)


def test_batch_flags_degenerate_sets_without_nan():
    good = np.random.default_rng(0).normal(size=(3, 3))
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    rotation, translation, ok = fit_rigid_batch(np.stack((good, line)), np.stack((good, line)))
    assert ok.tolist() == [True, False]
    assert np.isfinite(rotation).all() and np.isfinite(translation).all()
    np.testing.assert_allclose(rotation[0], np.eye(3), atol=1e-12)


def test_correspondence_weights_follow_the_formula():
    scores = np.array([0.8, -0.2])
    observed = np.array([[1.0, 1.0, 1.0], [2.0, 0.0, 0.0]])
    landmark = np.array([[2.0, 2.0, 2.0], [1.0, 0.0, 0.0]])  # completeness 0.5 and min(1, 2) = 1
    np.testing.assert_allclose(correspondence_weights(scores, observed, landmark, "both"), [0.4, 0.0])
    np.testing.assert_allclose(correspondence_weights(scores, observed, landmark, "sim"), [0.8, 0.0])
    np.testing.assert_allclose(correspondence_weights(scores, observed, landmark, "com"), [0.5, 1.0])
    np.testing.assert_allclose(correspondence_weights(scores, observed, landmark, "none"), [1.0, 1.0])


def test_umeyama_recovers_a_known_similarity_and_rigid_pose():
    rng = np.random.default_rng(4)
    source = rng.normal(size=(40, 3)) * [3.0, 2.0, 1.0]
    rotation = Rotation.from_rotvec([0.3, -1.1, 2.0]).as_matrix()
    translation = np.array([1.5, -4.0, 0.25])
    target = 2.7 * source @ rotation.T + translation
    similarity = fit_similarity(source, target)
    assert similarity.scale == pytest.approx(2.7, abs=1e-12)
    np.testing.assert_allclose(similarity.pose.rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(similarity.pose.translation, translation, atol=1e-11)
    np.testing.assert_allclose(similarity.apply(source), target, atol=1e-11)
    np.testing.assert_allclose(similarity.matrix()[:3, :3], 2.7 * rotation, atol=1e-12)
    rigid = fit_similarity(source, source @ rotation.T + translation, with_scale=False)
    assert rigid.scale == 1.0
    np.testing.assert_allclose(rigid.pose.translation, translation, atol=1e-11)
    # the rigid fit of scaled points is not the similarity: scale is reported, not absorbed
    noisy = target + rng.normal(scale=0.01, size=target.shape)
    assert fit_similarity(source, noisy).scale == pytest.approx(2.7, abs=0.01)


def test_umeyama_refuses_collinear_points():
    line = np.outer(np.arange(5.0), [1.0, 2.0, 0.5])
    with pytest.raises(DegeneratePoseError, match="collinear"):
        fit_similarity(line, 2 * line)


def _numpy_fit(source, target, weights):
    """The weighted fit written with numpy (einsum, np.linalg), the compiled moments' reference."""
    total = weights.sum(axis=1)
    w = weights / np.where(total > 0, total, 1.0)[:, None]
    mean_source, mean_target = np.einsum("bp,bpi->bi", w, source), np.einsum("bp,bpi->bi", w, target)
    centred_source, centred_target = source - mean_source[:, None], target - mean_target[:, None]
    u, _, vt = np.linalg.svd(np.einsum("bp,bpi,bpj->bij", w, centred_target, centred_source))
    sign = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= np.where(sign == 0, 1.0, sign)[:, None]
    rotation = u @ vt
    variances = [np.linalg.eigvalsh(np.einsum("bp,bpi,bpj->bij", w, c, c)) for c in (centred_source, centred_target)]
    ok = (total > 0) & np.logical_and(*[v[:, 1] > np.maximum(RELATIVE_SPREAD**2 * v[:, 2], MIN_SPREAD_M**2) for v in variances])
    rotation[~ok] = np.eye(3)
    translation = mean_target - np.einsum("bij,bj->bi", rotation, mean_source)
    translation[~ok] = 0.0
    ratio = [np.where(v[:, 2] > 0, np.sqrt(np.maximum(v[:, 1], 0) / np.where(v[:, 2] > 0, v[:, 2], 1)), 0) for v in variances]
    return rotation, translation, ok, np.minimum(*ratio)


def test_batch_fits_are_the_numpy_formulation_to_the_bit():
    """Degenerate sets included: collinear, zero weights, fewer than 3 points."""
    rng = np.random.default_rng(7)
    for trial in range(300):
        count, points = int(rng.integers(1, 7)), int(rng.integers(1, 25))
        source = rng.normal(size=(count, points, 3)) * (0.01, 1.0, 30.0)[trial % 3]
        target = source @ np.linalg.qr(rng.normal(size=(3, 3)))[0] + rng.normal(size=(count, 1, 3))
        target += rng.normal(scale=0.05, size=target.shape)
        weights = rng.random((count, points)) * (rng.random((count, points)) > 0.2)
        if trial % 5 == 0:
            source[..., 1], source[..., 2] = 2 * source[..., 0], 0.0  # a row
        if trial % 13 == 0:
            weights[0] = 0.0
        expected = _numpy_fit(source, target, weights)
        for got, want in zip(fit_rigid_conditioned(source, target, weights), expected):
            np.testing.assert_array_equal(got, want)


def test_degenerate_batch_fits_are_the_numpy_formulation_to_the_bit():
    """Hand-made sets: a mirror image (the sign fix), identical points (a zero cross-covariance), a row, a
    plane, -0 coordinates, exact zero weights, two points, each fitted alone and all in one batch."""
    rng = np.random.default_rng(3)
    spread = rng.normal(size=(6, 3))
    sets = [(spread, spread * (1.0, 1.0, -1.0)), (np.ones((6, 3)), np.ones((6, 3)) * 2.0),
            (np.outer(np.arange(6.0), (1.0, 2.0, 3.0)), spread), (spread * (1.0, 1.0, 0.0), spread),
            (np.full((6, 3), -0.0), spread), (spread, spread @ random_rotation(rng).T + 5.0),
            (spread[:2].repeat(3, axis=0), spread)]
    weights = [np.ones(6), np.ones(6), np.ones(6), rng.random(6), np.ones(6), np.r_[0.0, 0.0, rng.random(4)],
               np.ones(6)]
    source, target, weights = np.array([s for s, _ in sets]), np.array([t for _, t in sets]), np.array(weights)
    expected = _numpy_fit(source, target, weights)
    for got, want in zip(fit_rigid_conditioned(source, target, weights), expected):
        np.testing.assert_array_equal(got, want)
    for b in range(len(sets)):
        for got, want in zip(fit_rigid_conditioned(source[b:b + 1], target[b:b + 1], weights[b:b + 1]), expected):
            np.testing.assert_array_equal(got, want[b:b + 1])
    assert expected[2].tolist() == [True, False, False, True, False, True, False]


def test_sets_that_are_not_finite_are_flagged_and_leave_the_others_alone():
    """NaN or inf in a set: not ok, the identity, never NaN; the finite sets beside it fit as alone."""
    rng = np.random.default_rng(5)
    source = rng.normal(size=(4, 8, 3))
    target = source @ random_rotation(rng).T + 1.0
    weights = rng.random((4, 8))
    source[1, 3, 0], target[2, 0, 2], weights[3, 4] = np.nan, np.inf, np.nan
    with np.errstate(invalid="ignore"):
        rotation, translation, ok, measure = fit_rigid_conditioned(source, target, weights)
    assert ok.tolist() == [True, False, False, False]
    assert np.array_equal(rotation[1:], np.broadcast_to(np.eye(3), (3, 3, 3))) and not translation[1:].any()
    for got, want in zip((rotation, translation, ok, measure), fit_rigid_conditioned(source[:1], target[:1], weights[:1])):
        np.testing.assert_array_equal(got[:1], want)


def test_the_sign_fix_is_numpys_determinant_sign_to_the_bit():
    """`_proper` flips u's third column where det(u vt) < 0, as np.sign(np.linalg.det(u @ vt)) says, on
    rotations and reflections of every kind, exact (0 and -0 entries) and rounded, and NaN alike."""
    from clipclique.pose import _proper

    rng = np.random.default_rng(9)
    exact = [np.eye(3), np.diag([1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, -1.0]), np.eye(3)[[1, 0, 2]],
             np.array([[-0.0, 1.0, 0.0], [1.0, -0.0, 0.0], [0.0, 0.0, -1.0]])]
    rounded = [np.linalg.qr(rng.normal(size=(3, 3)))[0] * rng.choice((-1.0, 1.0), 3) for _ in range(400)]
    u = np.array([m for m in exact for _ in exact] + rounded[:200] + [np.full((3, 3), np.nan)])
    vt = np.array([m for _ in exact for m in exact] + rounded[200:] + [np.eye(3)])
    with np.errstate(invalid="ignore"):
        sign = np.sign(np.linalg.det(u @ vt))
    expected = u.copy()
    expected[:, :, 2] *= np.where(sign == 0, 1.0, sign)[:, None]
    _proper(u, vt)
    np.testing.assert_array_equal(u, expected)
    assert np.array_equal(np.signbit(u), np.signbit(expected))
    assert (sign[:-1] < 0).sum() > 50 and np.isnan(sign[-1])


def test_public_linear_algebra_stands_in_for_numpys_gufuncs_to_the_bit():
    """Where a numpy version has moved its private LAPACK gufuncs, the public wrappers give the same
    bits, and NaN (not LinAlgError for the whole stack) for a matrix holding NaN."""
    from clipclique.pose import _private_linalg, _public_linalg

    private, public = _private_linalg(), _public_linalg()
    assert private is not None  # this numpy has them: the fast path is the one tested everywhere else
    rng = np.random.default_rng(4)
    matrices = rng.normal(size=(40, 3, 3))
    symmetric = matrices @ np.swapaxes(matrices, 1, 2)
    for fast, stand_in, given in zip(private, public, (matrices, symmetric)):
        expected, got = fast(given), stand_in(given)
        for a, b in zip(expected if isinstance(expected, tuple) else (expected,), got if isinstance(got, tuple) else (got,)):
            assert np.array_equal(a, b)
    broken = matrices.copy()
    broken[7, 1, 2] = np.nan
    u, s, vt = public[0](broken)
    assert np.isnan(s[7]).all() and np.array_equal(s[:7], private[0](matrices[:7])[1])
    assert np.isnan(public[1](np.where(np.isnan(broken), np.nan, symmetric))[7]).all()


def numpy_weights(scores, observed_axes, landmark_axes, mode):
    """`correspondence_weights` as the callers wrote it with numpy (the reference the compiled pass must equal)."""
    if mode == "none":
        return np.ones(len(scores))
    completeness = np.minimum(1.0, np.sqrt(np.einsum("ij,ij->i", observed_axes, observed_axes)
                                           / np.maximum(np.einsum("ij,ij->i", landmark_axes, landmark_axes), 1e-12)))
    if mode == "com":
        return completeness
    similarity = np.maximum(scores, 0.0)
    return similarity * completeness if mode == "both" else similarity


@pytest.mark.parametrize("mode", ["none", "sim", "com", "both"])
def test_correspondence_weights_are_the_numpy_formula_to_the_bit(mode):
    rng = np.random.default_rng(11)
    scores = rng.choice([-0.5, -0.0, 0.0, 0.3, 0.8, 1.0, np.nan], size=200)
    observed, landmark = rng.uniform(0.0, 0.4, (200, 3)), rng.uniform(0.0, 0.4, (200, 3))
    observed[3], landmark[5] = 0.0, 0.0
    got = correspondence_weights(scores, observed, landmark, mode)
    assert got.tobytes() == numpy_weights(scores, observed, landmark, mode).tobytes()


@pytest.mark.parametrize("mode", ["none", "sim", "com", "both"])
def test_weighted_sets_are_the_padded_numpy_construction_to_the_bit(mode):
    """Sets of 0 to 19 pairs padded with a pair at weight 0, scores negative, -0, 0 and NaN, axes with a zero
    norm: the centres and `valid * correspondence_weights(...)` as the callers wrote them with numpy."""
    rng = np.random.default_rng(10)
    observed_centers, observed_axes = rng.normal(size=(12, 3)), rng.uniform(0.0, 0.4, (12, 3))
    landmark_centers, landmark_axes = rng.normal(size=(30, 3)), rng.uniform(0.0, 0.4, (30, 3))
    observed_axes[3], landmark_axes[5] = 0.0, 0.0
    for trial in range(60):
        counts = rng.integers(0, 20, int(rng.integers(1, 8)))
        pairs = np.column_stack((rng.integers(0, 12, counts.sum()), rng.integers(0, 30, counts.sum())))
        scores = rng.choice([-0.5, -0.0, 0.0, 0.3, 0.8, 1.0, np.nan], size=counts.sum())
        pad = (int(rng.integers(0, 12)), int(rng.integers(0, 30)), float(rng.choice([0.0, 0.7, np.nan])))
        valid = np.arange(max(counts.max(), 0)) < counts[:, None]
        obs, lm, score = np.full(valid.shape, pad[0]), np.full(valid.shape, pad[1]), np.full(valid.shape, pad[2])
        obs[valid], lm[valid], score[valid] = pairs[:, 0], pairs[:, 1], scores
        expected = valid * numpy_weights(score.ravel(), observed_axes[obs].reshape(-1, 3),
                                         landmark_axes[lm].reshape(-1, 3), mode).reshape(valid.shape)
        source, target, weights = weighted_sets(pairs, scores, counts, pad, (observed_centers, observed_axes),
                                                (landmark_centers, landmark_axes), mode)
        assert weights.tobytes() == expected.tobytes()
        assert source.tobytes() == observed_centers[obs].tobytes() and target.tobytes() == landmark_centers[lm].tobytes()


def _sets(rng, count, width):
    """`count` sets of `width` points: a noisy rigid copy each, weights with exact zeros."""
    source = rng.normal(size=(count, width, 3)) * 10.0 ** rng.uniform(-2, 1)
    target = source @ random_rotation(rng).T + rng.normal(size=(count, 1, 3))
    target += rng.normal(scale=0.05, size=source.shape)
    return source, target, rng.random((count, width)) * (rng.random((count, width)) > 0.2)


def _same_bits(got, want):
    for a, b in zip(got, want):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("count", [0, 1, 5])
def test_the_compiled_batch_fit_is_the_numpy_formulation_at_every_width(count):
    """Widths 1 to 40 (the weights' pairwise sum changes its order at 8, its padding zeros with it), random,
    collinear, a plane, zero weights: fit_rigid_conditioned is `_numpy_fit` and fit_rigid_batch its first three."""
    rng = np.random.default_rng(20 + count)
    for width in range(1, 41):
        source, target, weights = _sets(rng, count, width)
        if count > 1:
            source[0] = np.outer(rng.normal(size=width), (1.0, 2.0, -0.5))  # a row
            source[1, :, 2] = 0.0  # a plane
            weights[-1] = 0.0
        weights[:, width // 2:] = 0.0  # padded
        expected = _numpy_fit(source, target, weights)
        _same_bits(fit_rigid_conditioned(source, target, weights), expected)
        _same_bits(fit_rigid_batch(source, target, weights), expected[:3])


def test_the_compiled_batch_fit_sums_other_layouts_as_numpy_does():
    """Weights given transposed, as integers or float32: summed by numpy in their own layout and type, the
    gufunc passes' bits (and `_numpy_fit`'s, for float64)."""
    from clipclique.pose import _fitted_by_gufuncs

    rng = np.random.default_rng(21)
    for width in (3, 9, 17, 40):
        source, target, weights = _sets(rng, 4, width)
        transposed = np.asfortranarray(weights)
        _same_bits(fit_rigid_conditioned(source, target, transposed), _numpy_fit(source, target, transposed))
        for given in (transposed, (weights * 5).astype(np.int64), weights.astype(np.float32)):
            _same_bits(fit_rigid_conditioned(source, target, given), _fitted_by_gufuncs(source, target, given))


def test_sets_that_are_not_finite_fit_as_the_gufunc_passes_do():
    """NaN and inf in points and weights, and moments that overflow: those sets by `_fitted_by_gufuncs`
    (LAPACK's own answer to them), all four outputs to the bit, the finite ones beside them unchanged."""
    from clipclique.pose import _fitted_by_gufuncs

    rng = np.random.default_rng(22)
    for width in (1, 4, 9, 33):
        source, target, weights = _sets(rng, 6, width)
        source[1, 0, 0], target[2, -1, 2], weights[3, 0] = np.nan, np.inf, np.inf
        source[4] *= 1e160  # the covariances overflow
        target[5, 0, 1] = -np.inf
        with np.errstate(all="ignore"):
            fitted = fit_rigid_conditioned(source, target, weights)
            expected = _fitted_by_gufuncs(source, target, weights)
            _same_bits(fitted, expected)
            _same_bits(fit_rigid_batch(source, target, weights), expected[:3])
        assert not fitted[2][1:].any()
        _same_bits([a[:1] for a in fitted], _numpy_fit(source[:1], target[:1], weights[:1]))


def test_the_compiled_callers_fit_is_fit_rigid_batch_where_it_says_it_fitted():
    """`fit_rigid_sets` (refinement's fit inside its compiled call) against `fit_rigid_batch`: every width, no set,
    rows and zero weights to the bit; the sets that are not finite (NaN, inf, overflowing moments) flagged as not
    fitted, the others beside them still `fit_rigid_batch`'s."""
    rng = np.random.default_rng(23)
    for count, width in [(0, 3), (1, 1), (3, 7), (5, 8), (4, 13), (2, 40)]:
        source, target, weights = _sets(rng, count, width)
        if count > 2:
            source[0] = np.outer(rng.normal(size=width), (1.0, 2.0, -0.5))
            weights[1] = 0.0
        rotation, translation, ok, fitted = fit_rigid_sets(weights, source, target, lapack_routines())
        assert fitted.all() and fitted.shape == (count,)
        _same_bits((rotation, translation, ok), fit_rigid_batch(source, target, weights))
    source, target, weights = _sets(rng, 5, 6)
    source[1, 0, 0], target[2, -1, 2], weights[3, 0] = np.nan, np.inf, np.inf
    source[4] *= 1e160
    with np.errstate(all="ignore"):
        rotation, translation, ok, fitted = fit_rigid_sets(weights, source, target, lapack_routines())
        expected = fit_rigid_batch(source, target, weights)
    assert fitted.tolist() == [True, False, False, False, False]
    _same_bits((rotation[:1], translation[:1], ok[:1]), [a[:1] for a in expected])


def test_lapack_called_directly_gives_the_gufuncs_bits():
    """dgesdd and dsyevd from compiled code (scipy's LAPACK) against numpy's gufuncs: random, covariance-like,
    zero, rank 1 and 2, -0 entries, and a matrix whose triangles differ (the lower one is read)."""
    from numba import njit

    from clipclique.pose import _eigvalsh_of, _svd_of, _svd_views, _workspace

    @njit
    def decomposed(lapack, matrices):
        scratch = _workspace(lapack)
        left, right = _svd_views(scratch)
        u, vt, values = np.empty_like(matrices), np.empty_like(matrices), np.empty((len(matrices), 3))
        failures = 0
        for b in range(len(matrices)):
            failed = _svd_of(lapack, scratch, matrices, b)
            u[b], vt[b] = left, right
            eig_failed = _eigvalsh_of(lapack, scratch, matrices, b, values[b])
            failures += failed + eig_failed
        return u, vt, values, failures

    rng = np.random.default_rng(23)
    points = rng.normal(size=(3000, 8, 3))
    exact = [np.zeros((3, 3)), np.outer((1.0, 2.0, 3.0), (1.0, 2.0, 3.0)), np.diag((1.0, 0.0, -0.0)), np.eye(3),
             np.diag((2.0, 2.0, 1.0)), np.array([[1.0, 5.0, -0.0], [0.0, 1.0, 7.0], [2.0, 3.0, 1.0]])]
    matrices = np.concatenate((rng.normal(size=(3000, 3, 3)), np.einsum("bpi,bpj->bij", points, points) / 8,
                               np.array(exact)))
    u, vt, values, failures = decomposed(lapack_routines(), matrices)
    assert failures == 0
    expected_u, _, expected_vt = np.linalg.svd(matrices)
    assert u.tobytes() == expected_u.tobytes() and vt.tobytes() == expected_vt.tobytes()
    assert values.tobytes() == np.linalg.eigvalsh(matrices).tobytes()


def test_the_rotation_and_translation_are_numpys_matmul_and_einsum_to_the_bit():
    """u @ vt (OpenBLAS's dgemm: fused multiply-adds) and mean_target - einsum("bij,bj->bi", ...) of orthogonal,
    general and exact matrices with 0, -0 and ties."""
    from numba import njit

    from clipclique.pose import _rotation_of, _translation_of

    @njit
    def composed(u, vt, mean_source, mean_target):
        rotation, translation = np.empty_like(u), np.empty_like(mean_source)
        for b in range(len(u)):
            _rotation_of(u[b], vt[b], rotation[b])
            _translation_of(rotation[b], mean_source, mean_target, b, translation[b])
        return rotation, translation

    rng = np.random.default_rng(24)
    orthogonal = np.linalg.qr(rng.normal(size=(4000, 3, 3)))[0]
    exact = rng.choice([0.0, -0.0, 1.0, -1.0, 0.5], size=(600, 3, 3))
    u = np.concatenate((orthogonal[:2000], rng.normal(size=(1000, 3, 3)), exact[:300]))
    vt = np.concatenate((orthogonal[2000:], rng.normal(size=(1000, 3, 3)), exact[300:]))
    mean_source = np.concatenate((rng.normal(size=(3000, 3)), rng.choice([0.0, -0.0, 2.0, -1.0], size=(300, 3))))
    mean_target = np.concatenate((rng.normal(size=(3000, 3)), rng.choice([0.0, -0.0, 1.0], size=(300, 3))))
    rotation, translation = composed(u, vt, mean_source, mean_target)
    assert rotation.tobytes() == (u @ vt).tobytes()
    assert translation.tobytes() == (mean_target - np.einsum("bij,bj->bi", rotation, mean_source)).tobytes()


def test_a_spread_told_without_eigenvalues_is_never_wrong_and_usually_told():
    """`_surely_spread` says True only where LAPACK's eigenvalues pass `_spread_ok`: on sets thinned towards a
    row and a point across 14 decades (the thresholds' neighbourhood); and it tells ordinary sets, whose
    eigenvalues the batch fit then skips."""
    from clipclique.pose import _spread_ok, _surely_spread

    rng = np.random.default_rng(25)
    told = untold = collinear = 0
    for trial in range(6000):
        points = rng.normal(size=(int(rng.integers(3, 12)), 3)) * 10.0 ** rng.uniform(-7, 3)
        thin = 10.0 ** rng.uniform(-12, 0)
        points[:, 1] = points[:, 0] * rng.normal() + points[:, 1] * thin
        points[:, 2] = points[:, 0] * rng.normal() + points[:, 2] * thin * rng.uniform(0, 1)
        centred = points - points.mean(axis=0)
        covariance = centred.T @ centred / len(points)
        covariance[0, 1] = np.nextafter(covariance[0, 1], np.inf)  # the upper triangle is not read
        sure, spread = _surely_spread(covariance[None], 0), _spread_ok(np.linalg.eigvalsh(covariance))
        assert spread or not sure
        told, untold, collinear = told + (sure and spread), untold + (spread and not sure), collinear + (not spread)
    assert told > 1000 and untold > 100 and collinear > 1000  # (1363, 346, 4291)
    ordinary = [_surely_spread(np.cov(rng.normal(size=(6, 3)).T)[None], 0) for _ in range(500)]
    assert all(ordinary)


def test_nonzero_counts_are_numpys_count_nonzero():
    """0 and -0 do not count, NaN and inf do; no rows, no columns, one of each."""
    rng = np.random.default_rng(26)
    for rows, width in [(0, 3), (3, 0), (1, 1), (5, 40), (70, 13)]:
        weights = rng.choice([0.0, -0.0, 0.5, np.nan, np.inf, 1e-300], size=(rows, width))
        assert nonzero_counts(weights).tobytes() == np.count_nonzero(weights, axis=1).astype(np.int64).tobytes()


def test_batch_shapes_that_disagree_are_refused():
    """The compiled pass reads its arrays unchecked: shapes that disagree are a ValueError, not a stray read."""
    source = np.zeros((2, 4, 3))
    for target, weights in [(np.zeros((2, 5, 3)), np.ones((2, 4))), (source, np.ones((2, 5))), (source, np.ones(4)),
                            (np.zeros((2, 4, 2)), np.ones((2, 4)))]:
        with pytest.raises(ValueError, match="must be"):
            fit_rigid_conditioned(source, target, weights)
    with pytest.raises(ValueError, match="must be"):
        fit_rigid_batch(np.zeros((4, 3)), np.zeros((4, 3)))


def test_a_sets_finiteness_is_numpys_isfinite_of_its_rows():
    """`_finite_at` number by number against numpy's `np.isfinite(row).all()` of the set's means, cross-covariance
    and both covariances: every entry of set 1 in turn NaN, inf or -inf (-0 and 0 are finite), set 0 and 2 left
    finite beside it."""
    from clipclique.pose import _finite_at

    rng = np.random.default_rng(31)
    arrays = [rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), rng.normal(size=(3, 3, 3)), rng.normal(size=(2, 3, 3, 3))]
    arrays[2][1, 0, 0], arrays[3][1, 1, 2, 2] = -0.0, 0.0

    def expected(b):
        return bool(np.isfinite(arrays[0][b]).all() and np.isfinite(arrays[1][b]).all()
                    and np.isfinite(arrays[2][b]).all() and np.isfinite(arrays[3][:, b]).all())

    assert [_finite_at(b, *arrays) for b in range(3)] == [True, True, True]
    for array in arrays:
        set_one = array[1] if array.ndim < 4 else array[:, 1]
        for index in np.ndindex(set_one.shape):
            for value in (np.nan, np.inf, -np.inf):
                kept = set_one[index]
                set_one[index] = value
                assert [_finite_at(b, *arrays) for b in range(3)] == [expected(b) for b in range(3)] == [True, False, True]
                set_one[index] = kept
