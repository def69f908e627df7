"""The compiled neighbour pass over depth pixels against the plain pixel-by-pixel pass."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clipclique.perception.depth import _depth_points


def sequential_points(depth: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray, k: int,
                      radius: int) -> tuple[np.ndarray, np.ndarray]:
    """The neighbour pass pixel by pixel in plain Python, in the compiled pass's order of arithmetic:
    each pixel's distances summed in window order, then its n - k farthest taken off, largest first."""
    height, width = mask.shape
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    valid = mask & np.isfinite(depth) & (depth > 0)
    point = {(v, u): ((u - cx) * float(depth[v, u]) / fx, (v - cy) * float(depth[v, u]) / fy, float(depth[v, u]))
             for v, u in zip(*np.nonzero(valid))}
    points, spread = [], []
    for (v, u), p in point.items():
        near = [math.sqrt(square(q[0] - p[0]) + square(q[1] - p[1]) + square(q[2] - p[2]))
                for dv in range(-radius, radius + 1) for du in range(-radius, radius + 1)
                if (dv or du) and (q := point.get((v + dv, u + du))) is not None]
        total = 0.0
        for distance in near:
            total += distance
        for distance in sorted(near, reverse=True)[:max(len(near) - k, 0)]:
            total -= distance
        points.append(p)
        spread.append(total / min(len(near), k) if near else math.inf)
    return np.array(points).reshape(-1, 3), np.array(spread)


def square(value: float) -> float:
    """value * value, as compiled code squares (Python's ** 2 goes through C's pow)."""
    return value * value


@pytest.mark.parametrize(("k", "radius"), [(20, 2), (3, 1), (8, 1), (30, 3), (48, 3), (5, 2)])
def test_neighbour_pass_gives_the_sequential_values(k, radius):
    """Holes, NaN, infinite, -0 and negative depths, a ragged mask, rows of a single pixel and pixels without
    neighbours: every point and spread equals the plain pixel-by-pixel pass within rounding (the compiled pass computes
    each distance
    once for both of its pixels and runs the rows vectorized)."""
    rng = np.random.default_rng(k + radius)
    depth = (2.0 + rng.normal(0, 0.05, (23, 31))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = np.nan
    depth[rng.random(depth.shape) < 0.1] = 0.0
    for unusable in (np.inf, -np.inf, -0.0, -1.5):  # none of them a point
        depth[rng.random(depth.shape) < 0.02] = unusable
    mask = rng.random(depth.shape) < 0.7
    mask[5] = False
    mask[5, 17] = True  # a row with one pixel
    mask[8:15] = False
    mask[11, 15] = True  # a pixel without neighbours
    depth[11, 15] = 2.0
    mask[0, 0] = True  # a corner
    mask[20:, :] = rng.random((3, 31)) < 0.1  # sparse rows: pixels with few or no neighbours
    intrinsics = np.array([[50.0, 0, 14.3], [0, 52.0, 11.1], [0, 0, 1]])
    ours = _depth_points(k, radius)(depth, mask, intrinsics)
    theirs = sequential_points(depth, mask, intrinsics, k, radius)
    assert len(theirs[0]) > 150 and np.isinf(theirs[1]).any()
    for a, b in zip(ours[:2], theirs[:2]):
        np.testing.assert_allclose(a, b, rtol=1e-6 if a.dtype == np.float32 else 1e-12, atol=0)


def test_each_neighbour_pair_keeps_cache_files_of_its_own():
    """Closures of one name shared numba's cache index; two processes compiling two pairs at once gave one of
    them the other's machine code (`'descr' is NULL`)."""
    from pathlib import Path

    for k, radius in ((20, 2), (8, 1)):
        kernel = _depth_points(k, radius)
        kernel(np.full((4, 5), 2.0, np.float32), np.ones((4, 5), bool), np.eye(3))
        folder = Path(kernel._cache.cache_path)
        assert list(folder.glob(f"depth.depth_points_k{k}_r{radius}-*.nbi")), sorted(p.name for p in folder.iterdir())
