"""The compiled PCA box kernels against numpy: moments in point order, axes ordered as numpy did, numpy's
eigenvectors."""

from __future__ import annotations

import numpy as np

from clipclique.config import FitParams


def test_inlier_moments_sum_in_point_order():
    """Mean and scatter of the inliers, summed point by point in order (the bits the fit has always had),
    the scatter symmetric."""
    from clipclique.perception.ellipsoids import _extents, _inlier_moments

    rng = np.random.default_rng(7)
    points = rng.normal(0, 1, (200, 3)) * [0.3, 0.1, 0.05] + [1.0, -2.0, 3.0]
    spread = rng.uniform(0, 1, 200)
    count, mean, scatter = _inlier_moments(points, spread, 0.8)
    inliers = points[spread <= 0.8]
    want_mean = np.zeros(3)
    for point in inliers:
        want_mean += point
    want_mean /= len(inliers)
    want_scatter = np.zeros((3, 3))
    for point in inliers:
        want_scatter += np.outer(point - want_mean, point - want_mean)
    assert count == len(inliers) and np.array_equal(mean, want_mean) and np.array_equal(scatter, want_scatter)
    rotation = np.linalg.eigh(scatter)[1]
    low, high = _extents(points, spread, 0.8, mean, rotation)
    along = (inliers - mean) @ rotation
    np.testing.assert_allclose(low, along.min(axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(high, along.max(axis=0), rtol=0, atol=1e-12)


def numpy_box(points: np.ndarray, spread: np.ndarray, params: FitParams):
    """The PCA box as numpy wrote it before its ordering was compiled: the reference `_box` keeps."""
    from clipclique.perception.ellipsoids import _extents, _inlier_moments, _outlier_limit

    limit = _outlier_limit(spread, params.outlier_std_ratio)
    kept, mean, scatter = _inlier_moments(points, spread, limit)
    if kept < params.min_points:
        return None
    _, rotation = np.linalg.eigh(scatter)
    low, high = _extents(points, spread, limit, mean, rotation)
    center = mean + rotation @ ((low + high) / 2)
    axes = (high - low) / 2
    if not (np.isfinite(axes).all() and np.isfinite(rotation).all()) or axes.min() < params.min_axis:
        return None
    order = np.argsort(-axes)
    rotation = rotation[:, order]
    if np.linalg.det(rotation) < 0:
        rotation[:, 2] = -rotation[:, 2]
    return center, axes[order], rotation


def or_refused(fit, *arguments):
    """`fit(*arguments)`, or "raises" where numpy's eigh refuses the scatter."""
    try:
        return fit(*arguments)
    except np.linalg.LinAlgError:
        return "raises"


def test_box_orders_its_axes_as_numpy_did():
    """Random clouds of every elongation and orientation, axes exactly equal (a cube's corners: numpy's sort
    decides), flat and too small clouds, infinite spreads: the same boxes within rounding, or None."""
    from clipclique.perception.ellipsoids import Oriented, _box, _orientation

    rng = np.random.default_rng(11)
    params = FitParams(min_points=4)
    cases = []
    for _ in range(400):
        turn = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        scale = rng.choice([0.0, 0.004, 0.05, 0.3, 1.0], 3)
        points = rng.normal(0, 1, (int(rng.integers(3, 120)), 3)) * scale @ turn + rng.normal(0, 3, 3)
        spread = np.where(rng.random(len(points)) < 0.05, np.inf, rng.uniform(0, 1, len(points)))
        cases.append((points, spread))
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
    for stretch in ([1, 1, 1], [2, 1, 1], [1, 3, 1], [1, 1, 0.5], [0.5, 0.5, 2]):
        cases.append((corners * stretch, np.zeros(8)))
    for bad in (np.inf, -np.inf, np.nan, 1e300):  # a scatter that is not finite: numpy's eigh, as before
        points = rng.normal(0, 1, (40, 3))
        points[3, 1] = bad
        cases.append((points, np.zeros(40)))
    cases.append((np.array([[0.0, -0.0, 1.0], [-0.0, 0.0, 2.0], [1.0, -0.0, 0.0], [-0.0, 1.0, 0.0]] * 3), np.zeros(12)))
    outcomes = {"box": 0, "none": 0, "raises": 0}
    for points, spread in cases:
        got, want = or_refused(_box, points, spread, params), or_refused(numpy_box, points, spread, params)
        assert (got is None) == (want is None) and (got == "raises") == (want == "raises")
        outcomes["none" if got is None else "raises" if got == "raises" else "box"] += 1
        if got is not None and got != "raises":
            for a, b in zip(got, want):
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
            assert np.linalg.det(got[2]) > 0 and np.all(np.diff(got[1]) <= 0)
    assert outcomes["box"] > 80 and outcomes["none"] > 80 and outcomes["raises"] > 0
    assert _orientation(np.ones(3), np.eye(3), 0.01)[0] == Oriented.UNSURE  # the cube's ties took numpy's way
    assert _orientation(np.array([1.0, 2.0, 3.0]), np.eye(3)[:, [2, 1, 0]], 0.01)[0] == Oriented.DONE


def test_box_parts_eigenvectors_are_numpys():
    """numba's `eigh` in `_box_parts` (LAPACK's dsyevd, as numpy's) gives numpy's eigenvectors of the inliers'
    scatter, the same basis within rounding: random clouds, axis-aligned ones (a diagonal scatter), repeated and zero
    eigenvalues."""
    from clipclique.perception.ellipsoids import Oriented, _box_parts, _inliers

    rng = np.random.default_rng(5)
    checked = 0
    for trial in range(3000):
        scale = rng.choice([0.0, 1e-3, 0.05, 0.3, 1.0, 1.0], 3)
        turn = np.eye(3) if trial % 3 == 0 else np.linalg.qr(rng.normal(size=(3, 3)))[0]
        points = rng.normal(0, 1, (int(rng.integers(4, 200)), 3)) * scale @ turn + rng.normal(0, 3, 3)
        if trial % 5 == 0:
            points = np.round(points, 1)  # ties between coordinates
        spread = rng.uniform(0, 1, len(points))
        parts = _box_parts(points, spread, 2.0, 4, 0.0)
        _, _, mean, scatter = _inliers(points, spread, 2.0)
        if parts[0] == Oriented.DEGENERATE:
            continue
        assert parts[0] != Oriented.NOT_FINITE
        want = np.linalg.eigh(scatter)[1]
        assert parts[5].flags.c_contiguous
        np.testing.assert_allclose(parts[5], want, rtol=0, atol=1e-12)
        np.testing.assert_allclose(parts[3], mean, rtol=1e-12, atol=1e-12)
        checked += 1
    assert checked > 2500
