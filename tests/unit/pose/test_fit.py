import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.pose.fit import (
    MIN_SPREAD_M,
    RELATIVE_SPREAD,
    DegeneratePoseError,
    conditioning,
    correspondence_weights,
    fit_rigid,
    fit_rigid_batch,
    fit_rigid_conditioned,
    fit_rigid_sets,
    fit_sets,
    fit_similarity,
    nonzero_counts,
    weighted_sets,
)
from clipclique.sim.poses import random_rotation


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


ROTATION_ATOL = 1e-9  # poses: well within issue 34's 1e-6 m and 1e-6 rad
RTOL, ATOL = 1e-9, 1e-12  # conditioning


def kabsch(source, target, weights):
    """The weighted Kabsch fit by numpy's SVD, the reference: rotation, translation, and the gap that bounds
    how well any solver can fix the rotation, (s2 + sign(det) s3) / s1 of the cross-covariance."""
    w = weights / weights.sum()
    mean_source, mean_target = w @ source, w @ target
    cross = ((target - mean_target) * w[:, None]).T @ (source - mean_source)
    u, singular, vt = np.linalg.svd(cross)
    sign = np.sign(np.linalg.det(u @ vt)) or 1.0
    u[:, 2] *= sign
    rotation = u @ vt
    gap = (singular[1] + np.sign(np.linalg.det(cross)) * singular[2]) / singular[0]
    return rotation, mean_target - rotation @ mean_source, gap


def numpy_fit(source, target, weights):
    """The batch fit written with numpy: Kabsch per set, ok and the conditioning by np.linalg.eigvalsh."""
    rotation, translation = np.tile(np.eye(3), (len(source), 1, 1)), np.zeros((len(source), 3))
    ok, measure = np.zeros(len(source), bool), np.zeros(len(source))
    for b in range(len(source)):
        total = weights[b].sum()
        if not total > 0:
            continue
        w = weights[b] / total
        variances = [np.linalg.eigvalsh(np.einsum("p,pi,pj->ij", w, c - w @ c, c - w @ c))
                     for c in (source[b], target[b])]
        ok[b] = all(v[1] > max(RELATIVE_SPREAD**2 * v[2], MIN_SPREAD_M**2) for v in variances)
        measure[b] = min(np.sqrt(max(v[1], 0.0) / v[2]) if v[2] > 0 else 0.0 for v in variances)
        if ok[b]:
            rotation[b], translation[b], _ = kabsch(source[b], target[b], weights[b])
    return rotation, translation, ok, measure


def rigid_copies(rng, count, width, scale=1.0, noise=0.05):
    """`count` sets of `width` points and their noisy rigid copies; weights with exact zeros."""
    source = rng.normal(size=(count, width, 3)) * scale
    target = np.einsum("bij,bpj->bpi", np.array([random_rotation(rng) for _ in range(count)]).reshape(-1, 3, 3),
                       source) + rng.normal(size=(count, 1, 3)) + rng.normal(scale=noise * scale, size=source.shape)
    return source, target, rng.random((count, width)) * (rng.random((count, width)) > 0.2)


def assert_fits_agree(got, want):
    """Poses within ROTATION_ATOL where the reference fixes one, ok alike, the conditioning within RTOL."""
    rotation, translation, ok, measure = got
    np.testing.assert_array_equal(ok, want[2])
    np.testing.assert_allclose(rotation, want[0], rtol=0, atol=ROTATION_ATOL)
    np.testing.assert_allclose(translation, want[1], rtol=0, atol=ROTATION_ATOL)
    np.testing.assert_allclose(measure[ok], want[3][ok], rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("scale", [0.01, 1.0, 30.0])
def test_batch_fits_are_numpys_kabsch_on_random_sets(scale):
    """Sets of 3 to 24 points, weights with zeros, whole batches: Kabsch's pose, ok and conditioning; the rotations
    proper. A set of fewer than 3 positive weights, or all zero, is not ok."""
    rng = np.random.default_rng(int(scale * 100))
    fitted = 0
    for _ in range(100):
        source, target, weights = rigid_copies(rng, int(rng.integers(1, 7)), int(rng.integers(3, 25)), scale)
        got = fit_rigid_conditioned(source, target, weights)
        assert_fits_agree(got, numpy_fit(source, target, weights))
        np.testing.assert_allclose(np.linalg.det(got[0]), 1.0, atol=1e-12)
        assert not got[2][np.count_nonzero(weights, axis=1) < 3].any()
        fitted += got[2].sum()
    assert fitted > 250


def test_three_point_sets_give_the_exact_pose():
    """Three points (a plane: the common case) moved exactly: the pose to 1e-12, rotations up to a half turn."""
    rng = np.random.default_rng(1)
    for trial in range(500):
        source = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-1, 1)
        rotation = Rotation.from_rotvec(rng.normal(size=3) * rng.uniform(0, np.pi)).as_matrix()
        translation = rng.normal(size=3) * 5
        pose = fit_rigid(source, source @ rotation.T + translation, rng.uniform(0.1, 1.0, 3))
        np.testing.assert_allclose(pose.rotation, rotation, atol=1e-12)
        np.testing.assert_allclose(pose.translation, translation, atol=1e-11)


@pytest.mark.parametrize("points", [3, 5])
def test_half_turns_are_exact(points):
    """Rotations by pi and a hair less about random axes: the quaternion's scalar part is ~0 there."""
    rng = np.random.default_rng(points)
    for angle in (np.pi, np.pi - 1e-9, np.pi - 1e-5):
        for _ in range(200):
            axis = rng.normal(size=3)
            rotation = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
            source = rng.normal(size=(points, 3))
            pose = fit_rigid(source, source @ rotation.T + 1.0)
            np.testing.assert_allclose(pose.rotation, rotation, atol=1e-12)
    source = rng.normal(size=(points, 3))
    target = source @ np.diag([-1.0, -1.0, 1.0]) + rng.normal(scale=0.01, size=(points, 3))
    weights = np.ones(points)
    np.testing.assert_allclose(fit_rigid(source, target).rotation, kabsch(source, target, weights)[0], atol=1e-12)


@pytest.mark.parametrize("thin", [1e-2, 1e-3, 1e-4, 1e-5])
def test_nearly_collinear_sets_are_fixed_as_well_as_kabsch_fixes_them(thin):
    """Points `thin` of their length off a row, moved exactly: the rotation about the row is fixed only to eps
    over the gap (about thin squared), by Kabsch's SVD as by the quaternion; both agree to that, and with the
    truth. Thinner than the spread test (1e-7 of the length) they are not ok."""
    rng = np.random.default_rng(int(-np.log10(thin)))
    for trial in range(200):
        source = np.outer(rng.normal(size=5), rng.normal(size=3)) + rng.normal(size=(5, 3)) * thin
        rotation = random_rotation(rng)
        target = source @ rotation.T + 2.0
        weights = rng.uniform(0.1, 1.0, 5)
        rotations, _, ok, measure = fit_rigid_conditioned(source[None], target[None], weights[None])
        got, (expected, _, gap) = rotations[0], kabsch(source, target, weights)
        assert ok[0] and measure[0] > 0.1 * thin
        assert np.abs(got - expected).max() * gap < 1e-13 and np.abs(got - rotation).max() * gap < 1e-13
        if thin >= 1e-3:
            np.testing.assert_allclose(got, rotation, atol=1e-7)
    line = np.outer(rng.normal(size=5), rng.normal(size=3)) + rng.normal(size=(5, 3)) * 1e-8
    assert not fit_rigid_batch(line[None], line[None] + 1.0)[2][0]


def test_the_spread_test_keeps_its_thresholds():
    """A rectangle d wide: spread (sigma_2 = d / 2) above MIN_SPREAD_M, or RELATIVE_SPREAD of its length."""
    def ok(length, width):
        corners = np.array([[0, 0, 0], [length, 0, 0], [0, width, 0], [length, width, 0.0]])
        return bool(fit_rigid_batch(corners[None], corners[None] + 1.0)[2][0])

    assert ok(1.0, 2.2 * MIN_SPREAD_M) and not ok(1.0, 1.8 * MIN_SPREAD_M)
    assert ok(1e4, 1.1 * RELATIVE_SPREAD * 1e4) and not ok(1e4, 0.9 * RELATIVE_SPREAD * 1e4)


def test_reflections_give_the_nearest_rotation():
    """Mirror images (det of the cross-covariance < 0): a proper rotation, Kabsch's sign-fixed one."""
    rng = np.random.default_rng(8)
    for _ in range(300):
        source = rng.normal(size=(int(rng.integers(3, 9)), 3))
        target = source * rng.choice([-1.0, 1.0], 3) @ random_rotation(rng).T
        if np.linalg.det(target.T @ source) > 0:
            target = -target
        weights = rng.uniform(0.1, 1.0, len(source))
        rotation, _, ok, _ = fit_rigid_conditioned(source[None], target[None], weights[None])
        expected, _, gap = kabsch(source, target, weights)
        assert ok[0] and np.linalg.det(rotation[0]) == pytest.approx(1.0, abs=1e-12)
        if gap > 1e-6:
            np.testing.assert_allclose(rotation[0], expected, atol=1e-12 / gap)


def test_fits_are_deterministic_and_independent_of_their_batch():
    """Each set's fit alone, in a batch, and again: the same bytes (one machine's determinism)."""
    rng = np.random.default_rng(12)
    source, target, weights = rigid_copies(rng, 9, 7)
    batch = fit_rigid_conditioned(source, target, weights)
    for got, again in zip(batch, fit_rigid_conditioned(source, target, weights)):
        np.testing.assert_array_equal(got, again)
    for b in range(9):
        for got, alone in zip(batch, fit_rigid_conditioned(source[b:b + 1], target[b:b + 1], weights[b:b + 1])):
            np.testing.assert_array_equal(got[b:b + 1], alone)


def test_degenerate_sets_are_flagged_with_the_identity():
    """Identical points, a row, two points repeated, zero weights, weights summing to 0: not ok, the identity, a
    conditioning of 0 where nothing spreads; a plane and a good set beside them fit."""
    rng = np.random.default_rng(3)
    spread = rng.normal(size=(6, 3))
    sets = [(np.ones((6, 3)), np.ones((6, 3)) * 2.0), (np.outer(np.arange(6.0), (1.0, 2.0, 3.0)), spread),
            (spread[:2].repeat(3, axis=0), spread), (spread, spread + 1.0), (spread, spread + 1.0),
            (spread * (1.0, 1.0, 0.0), spread * (1.0, 1.0, 0.0)), (spread, spread @ random_rotation(rng).T)]
    weights = [np.ones(6), np.ones(6), np.ones(6), np.r_[0.0, 0.0, 0.0, 0.0, 1.0, 1.0], np.r_[1.0, -1.0, 0, 0, 0, 0],
               rng.random(6), np.ones(6)]
    source, target, weights = np.array([s for s, _ in sets]), np.array([t for _, t in sets]), np.array(weights)
    rotation, translation, ok, measure = fit_rigid_conditioned(source, target, weights)
    assert ok.tolist() == [False, False, False, False, False, True, True]
    np.testing.assert_array_equal(rotation[:5], np.broadcast_to(np.eye(3), (5, 3, 3)))
    np.testing.assert_array_equal(translation[:5], 0.0)
    np.testing.assert_allclose(measure[:5], 0.0, atol=1e-7)
    assert_fits_agree((rotation[5:], translation[5:], ok[5:], measure[5:]),
                      numpy_fit(source[5:], target[5:], weights[5:]))


def test_sets_that_are_not_finite_are_flagged_and_leave_the_others_alone():
    """NaN or inf in points or weights, moments that overflow: not ok, the identity, a conditioning of 0, never
    NaN; the finite sets beside them fit as alone."""
    rng = np.random.default_rng(5)
    source, target, weights = rigid_copies(rng, 7, 8)
    weights[:] = rng.uniform(0.1, 1.0, (7, 8))
    source[1, 3, 0], target[2, 0, 2], weights[3, 4], weights[4, 0] = np.nan, np.inf, np.nan, np.inf
    source[5] *= 1e160
    target[6, 0, 1] = -np.inf
    with np.errstate(all="ignore"):
        rotation, translation, ok, measure = fit_rigid_conditioned(source, target, weights)
    assert ok.tolist() == [True] + [False] * 6
    np.testing.assert_array_equal(rotation[1:], np.broadcast_to(np.eye(3), (6, 3, 3)))
    np.testing.assert_array_equal(translation[1:], 0.0)
    np.testing.assert_array_equal(measure[1:], 0.0)
    alone = fit_rigid_conditioned(source[:1], target[:1], weights[:1])
    for got, want in zip((rotation, translation, ok, measure), alone):
        np.testing.assert_array_equal(got[:1], want)


def test_the_compiled_callers_fit_is_fit_rigid_batch():
    """`fit_rigid_sets` (refinement's fit inside its compiled call, its spread test mostly without eigenvalues):
    `fit_rigid_batch`'s bytes, no set to many; so too for sets about the spread test's thresholds, where the
    eigenvalues decide, and for weights of both signs (a covariance that need not be semidefinite)."""
    rng = np.random.default_rng(23)
    for count, width in [(0, 3), (1, 1), (3, 7), (5, 8), (2, 40)]:
        source, target, weights = rigid_copies(rng, count, width)
        for got, want in zip(fit_rigid_sets(weights, source, target), fit_rigid_batch(source, target, weights)):
            assert got.shape == want.shape
            np.testing.assert_array_equal(got, want)
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    widths = np.array([1.0, 1e-3, 3e-5, 2.2 * MIN_SPREAD_M, 1.8 * MIN_SPREAD_M, 1.1e4 * RELATIVE_SPREAD,
                       0.9e4 * RELATIVE_SPREAD])
    lengths = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 1e4, 1e4])
    source = corners * np.column_stack((lengths, widths, widths))[:, None]
    source = np.concatenate((source, np.tile(rng.normal(size=(1, 4, 3)), (2, 1, 1))))
    target, weights = source + 1.0, np.ones((9, 4))
    weights[7:] = [[1.0, -0.5, 1.0, 1.0], [2.0, -1.0, -0.5, 0.1]]
    got, want = fit_rigid_sets(weights, source, target), fit_rigid_batch(source, target, weights)
    assert want[2].tolist() == [True, True, True, True, False, True, False, True, False]
    for got_array, want_array in zip(got, want):
        np.testing.assert_array_equal(got_array, want_array)


def test_eigenvalues_are_numpys_eigvalsh():
    """The covariances' eigenvalues against np.linalg.eigvalsh within 1e-14 of the matrix's norm: random, rank 1
    and 2 (zero and repeated eigenvalues), multiples of the identity, near ties, 1e-8 to 1e8 in scale."""
    from clipclique.pose.fit import _eigenvalues

    rng = np.random.default_rng(24)
    points = rng.normal(size=(2000, 6, 3)) * rng.choice([1e-4, 1.0, 1e4], (2000, 1, 3))
    points[::4, :, 2] = 0.0
    points[1::4] = np.outer(rng.normal(size=6), rng.normal(size=3))
    centred = points - points.mean(axis=1, keepdims=True)
    rotated = random_rotation(rng)
    exact = [np.zeros((3, 3)), np.eye(3), 5.0 * np.eye(3), rotated @ np.diag([2.0, 2.0, 1.0]) @ rotated.T,
             rotated @ np.diag([1.0, 1.0 + 1e-9, 1e-12]) @ rotated.T, np.diag([3.0, 0.0, 0.0])]
    matrices = np.concatenate((np.einsum("bpi,bpj->bij", centred, centred) / 6, np.array(exact)))
    scratch = np.empty((4, 4))
    for m in matrices:
        expected = np.linalg.eigvalsh(m)
        got = _eigenvalues(m, scratch)
        assert got[0] <= got[1] <= got[2]
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-14 * max(np.linalg.norm(m), 1e-300))


def test_conditioning_is_the_ratio_of_numpys_principal_variances():
    rng = np.random.default_rng(27)
    points, weights = rng.normal(size=(40, 7, 3)) * (3.0, 1.0, 0.2), rng.random((40, 7))
    w = weights / weights.sum(axis=1, keepdims=True)
    centred = points - np.einsum("bp,bpi->bi", w, points)[:, None]
    variances = np.linalg.eigvalsh(np.einsum("bp,bpi,bpj->bij", w, centred, centred))
    np.testing.assert_allclose(conditioning(points, weights), np.sqrt(variances[:, 1] / variances[:, 2]), rtol=RTOL,
                               atol=ATOL)
    assert conditioning(np.outer(np.arange(5.0), (1.0, 2.0, 3.0))) < 1e-7
    assert conditioning(np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0.0]])) == pytest.approx(1.0, rel=1e-12)


def numpy_weights(scores, observed_axes, landmark_axes, mode):
    """`correspondence_weights` written with numpy (the compiled pass's reference)."""
    if mode == "none":
        return np.ones(len(scores))
    completeness = np.minimum(1.0, np.sqrt(np.einsum("ij,ij->i", observed_axes, observed_axes)
                                           / np.maximum(np.einsum("ij,ij->i", landmark_axes, landmark_axes), 1e-12)))
    if mode == "com":
        return completeness
    similarity = np.maximum(scores, 0.0)
    return similarity * completeness if mode == "both" else similarity


@pytest.mark.parametrize("mode", ["none", "sim", "com", "both"])
def test_correspondence_weights_are_the_numpy_formula(mode):
    rng = np.random.default_rng(11)
    scores = rng.choice([-0.5, -0.0, 0.0, 0.3, 0.8, 1.0, np.nan], size=200)
    observed, landmark = rng.uniform(0.0, 0.4, (200, 3)), rng.uniform(0.0, 0.4, (200, 3))
    observed[3], landmark[5] = 0.0, 0.0
    got = correspondence_weights(scores, observed, landmark, mode)
    np.testing.assert_allclose(got, numpy_weights(scores, observed, landmark, mode), rtol=1e-12, atol=0)


@pytest.mark.parametrize("mode", ["none", "sim", "com", "both"])
def test_weighted_sets_are_the_padded_numpy_construction(mode):
    """Sets of 0 to 19 pairs padded with a pair at weight 0, scores negative, -0, 0 and NaN, axes with a zero
    norm: the centres, and the weights of numpy's construction where valid and exactly 0 where padded (a NaN pad
    score included)."""
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
        expected = np.where(valid, numpy_weights(score.ravel(), observed_axes[obs].reshape(-1, 3),
                                         landmark_axes[lm].reshape(-1, 3), mode).reshape(valid.shape), 0.0)
        source, target, weights = weighted_sets(pairs, scores, counts, pad, (observed_centers, observed_axes),
                                                (landmark_centers, landmark_axes), mode)
        np.testing.assert_allclose(weights, expected, rtol=1e-12, atol=0)
        np.testing.assert_array_equal(source, observed_centers[obs])
        np.testing.assert_array_equal(target, landmark_centers[lm])


def test_fit_sets_are_the_three_calls_and_the_numpy_mask():
    """`fit_sets` against `weighted_sets`, `fit_rigid_conditioned` and `ok & (nonzero_counts(weights) >= 3) &
    (measure >= floor)` (the calls it replaced): the same poses and conditioning exactly, the same mask and its
    `.all()`; sets of 0 to 7 pairs, zero and NaN scores (a NaN weight counts), a collinear set, floors exactly at a
    set's conditioning, 0, -inf and above every set; and an empty batch."""
    rng = np.random.default_rng(32)
    observed_centers, observed_axes = rng.normal(size=(12, 3)), rng.uniform(0.05, 0.4, (12, 3))
    landmark_centers, landmark_axes = rng.normal(size=(30, 3)), rng.uniform(0.05, 0.4, (30, 3))
    observed_centers[:3] = np.outer([0.0, 1.0, 2.0], [1.0, 0.5, 0.25])  # observations 0, 1, 2 in a row
    all_ok = some_not = 0
    for trial in range(300):
        counts = rng.integers(0, 8, int(rng.integers(0, 6)))
        pairs = np.column_stack((rng.integers(0, 12, counts.sum()), rng.integers(0, 30, counts.sum())))
        if trial % 7 == 0 and len(counts) and counts[0] >= 3:
            pairs[:3, 0] = [0, 1, 2]  # the first set begins with the row
        scores = rng.choice([0.0, 0.3, 0.8, 1.0, np.nan], p=[0.1, 0.3, 0.3, 0.25, 0.05], size=counts.sum())
        pad = (int(rng.integers(0, 12)), int(rng.integers(0, 30)), 0.5)
        observed, landmarks = (observed_centers, observed_axes), (landmark_centers, landmark_axes)
        source, target, weights = weighted_sets(pairs, scores, counts, pad, observed, landmarks, "both")
        rotation, translation, ok, measure = fit_rigid_conditioned(source, target, weights)
        floors = [0.0, -np.inf, 2.0, float(rng.uniform(0, 0.5))] + ([float(measure[0])] if len(measure) else [])
        for floor in floors:
            expected = ok & (nonzero_counts(weights) >= 3) & (measure >= floor)
            got = fit_sets(pairs, scores, counts, pad, observed, landmarks, "both", floor)
            for ours, theirs in zip(got[:4], (rotation, translation, expected, measure)):
                assert ours.dtype == theirs.dtype
                np.testing.assert_array_equal(ours, theirs)
            assert got[4] == expected.all()
            all_ok += bool(len(expected)) and bool(expected.all())
            some_not += not expected.all()
    assert all_ok > 50 and some_not > 200


def test_nonzero_counts_are_numpys_count_nonzero():
    """0 and -0 do not count, NaN and inf do; no rows, no columns, one of each."""
    rng = np.random.default_rng(26)
    for rows, width in [(0, 3), (3, 0), (1, 1), (5, 40), (70, 13)]:
        weights = rng.choice([0.0, -0.0, 0.5, np.nan, np.inf, 1e-300], size=(rows, width))
        np.testing.assert_array_equal(nonzero_counts(weights), np.count_nonzero(weights, axis=1))


def test_batch_shapes_that_disagree_are_refused():
    """The compiled pass reads its arrays unchecked: shapes that disagree are a ValueError, not a stray read."""
    source = np.zeros((2, 4, 3))
    for target, weights in [(np.zeros((2, 5, 3)), np.ones((2, 4))), (source, np.ones((2, 5))), (source, np.ones(4)),
                            (np.zeros((2, 4, 2)), np.ones((2, 4)))]:
        with pytest.raises(ValueError, match="must be"):
            fit_rigid_conditioned(source, target, weights)
    with pytest.raises(ValueError, match="must be"):
        fit_rigid_batch(np.zeros((4, 3)), np.zeros((4, 3)))
