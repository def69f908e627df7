"""Depth pixels as camera-frame points: back-projection, and the compiled pass that gives each pixel its mean
distance to its nearest neighbours in the image window (the outlier removal of an ellipsoid fit).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
from numba import njit


@functools.cache
def _depth_points(k: int, radius: int) -> Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The compiled pass `depth_points(depth, mask, intrinsics)` for `k` neighbours within `radius` pixels:
    `_neighbour_pass` with `k` and `radius` compiled in as constants (one cached compilation per pair; a closure
    over integers alone, so that numba's cache finds it again in the next process).

    Each pair is named apart (`depth_points_k20_r2`), so its cache files are its own: numba names them by the
    function's name, and closures of one name share an index whose entries number their data files, which two
    processes compiling two pairs at once numbered alike (one loaded the other's machine code and failed)."""

    def depth_points(depth: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _neighbour_pass(depth, mask, intrinsics, k, radius)

    depth_points.__qualname__ = f"depth_points_k{k}_r{radius}"
    return njit(cache=True)(depth_points)


@njit(inline="always")
def _neighbour_pass(depth: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray, k: int,
                   radius: int) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) camera-frame points of the pixels of `mask` with a finite positive depth (row-major),
    and (P,) the mean 3D distance of each to its k nearest such pixels within `radius` pixels
    (fewer where fewer exist; inf for a pixel with none).

    Inlined where it is called, with `k` and `radius` constants there (`_depth_points`), so that the
    compiler unrolls and vectorizes by them. The pass runs one window offset at a time over a whole row
    of pixels, on flat arrays indexed by unsigned integers, so that the compiler vectorizes the loop over
    the row (README, Observation stage). The distance between two pixels is computed once, by the earlier
    of the two in row-major order for its `ahead` offsets (its own row's right, the rows below), and read
    back by the later one: (a - b)^2 and (b - a)^2 are the same bits, and each pixel still sums its
    neighbours' distances in window order.
    """
    side = 2 * radius + 1
    drop = max(side * side - 1 - k, 0)  # a pixel has at most side^2 - 1 neighbours; the farthest beyond k are dropped
    ahead = radius + radius * side  # the offsets after a pixel in window order
    rows = radius + 1  # the rows of distances kept: a pixel's own and the `radius` rows above it
    height, width = mask.shape
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    # coordinates on a flat grid padded by `radius` invalid pixels: every window lies inside it
    pitch = width + 2 * radius
    size = (height + 2 * radius) * pitch
    x, y, z, valid = np.zeros(size), np.zeros(size), np.zeros(size), np.zeros(size, np.bool_)
    first, last = np.full(height, width), np.full(height, -1)  # each row's valid columns, for the row pass
    count = 0
    for v in range(height):  # branch-free: an invalid pixel writes the zeros it had
        at = np.uint64((v + radius) * pitch + radius)
        row_first, row_last, row_count = width, -1, 0
        for u in range(width):
            depth_vu = depth[v, u]
            usable = mask[v, u] and depth_vu > 0 and depth_vu < np.inf  # finite and positive
            p = at + np.uint64(u)
            x[p] = (u - cx) * depth_vu / fx if usable else 0.0
            y[p] = (v - cy) * depth_vu / fy if usable else 0.0
            z[p] = depth_vu if usable else 0.0
            valid[p] = usable
            row_count += usable
            row_first = min(row_first, u if usable else width)
            row_last = u if usable else row_last
        count += row_count
        first[v], last[v] = row_first, row_last
    points = np.empty((count, 3))
    spread = np.full(count, np.inf)
    distances = np.zeros((ahead, rows * pitch))  # per ahead offset, the last `rows` rows' distances, by column
    total, near_count = np.empty(width), np.empty(width, np.int64)
    farthest = np.empty((max(drop, 1), width))  # per pixel, the largest distances so far, largest first
    plan = np.empty((side * side - 1, 3), np.int64)  # per neighbour: its row of distances, where, its pixel
    i = 0
    for v in range(height):
        if last[v] < 0:
            continue
        span = last[v] + 1 - first[v]
        start = np.uint64((v + radius) * pitch + radius + first[v])  # the row's first pixel in the grid
        own = (v % rows) * pitch + radius + first[v]  # ... and in the rows of distances
        for offset in range(ahead):  # this row's distances to the pixels ahead
            to_row = 0 if offset < radius else 1 + (offset - radius) // side
            to_column = offset + 1 if offset < radius else (offset - radius) % side - radius
            neighbour = np.uint64((v + radius + to_row) * pitch + radius + first[v] + to_column)
            out, at = distances[offset], np.uint64(own)
            for s in range(span):
                t = np.uint64(s)
                p, q = start + t, neighbour + t
                out[at + t] = math.sqrt((x[q] - x[p]) ** 2 + (y[q] - y[p]) ** 2 + (z[q] - z[p]) ** 2)
        for s in range(span):
            t = np.uint64(s)
            total[t], near_count[t] = 0.0, 0
            for j in range(drop):
                farthest[j, t] = -1.0
        listed = 0
        for to_row in range(-radius, radius + 1):  # every neighbour in window order
            for to_column in range(-radius, radius + 1):
                if to_row == 0 and to_column == 0:
                    continue  # not its own neighbour
                behind = to_row < 0 or (to_row == 0 and to_column < 0)  # its distance was computed there
                down, right = (-to_row, -to_column) if behind else (to_row, to_column)  # the offset ahead
                plan[listed, 0] = right - 1 if down == 0 else radius + (down - 1) * side + right + radius
                behind_at = ((v + to_row + rows) % rows) * pitch + radius + first[v] + to_column
                plan[listed, 1] = behind_at if behind else own
                plan[listed, 2] = (v + radius + to_row) * pitch + radius + first[v] + to_column
                listed += 1
        for group in range(0, listed, 4):  # four neighbours a pass over the row: side^2 - 1 is a multiple of 8
            four = plan[group:group + 4]
            row1, at1, near1 = distances[four[0, 0]], np.uint64(four[0, 1]), np.uint64(four[0, 2])
            row2, at2, near2 = distances[four[1, 0]], np.uint64(four[1, 1]), np.uint64(four[1, 2])
            row3, at3, near3 = distances[four[2, 0]], np.uint64(four[2, 1]), np.uint64(four[2, 2])
            row4, at4, near4 = distances[four[3, 0]], np.uint64(four[3, 1]), np.uint64(four[3, 2])
            for s in range(span):  # branch-free: an absent neighbour adds 0 and inserts -1
                t = np.uint64(s)
                in1, in2, in3, in4 = valid[near1 + t], valid[near2 + t], valid[near3 + t], valid[near4 + t]
                carry1 = row1[at1 + t] if in1 else -1.0
                carry2 = row2[at2 + t] if in2 else -1.0
                carry3 = row3[at3 + t] if in3 else -1.0
                carry4 = row4[at4 + t] if in4 else -1.0
                total[t] = ((((total[t] + (carry1 if in1 else 0.0)) + (carry2 if in2 else 0.0))
                             + (carry3 if in3 else 0.0)) + (carry4 if in4 else 0.0))  # in window order
                near_count[t] += in1 + in2 + in3 + in4
                for j in range(drop):  # insert the four into the sorted farthest list
                    kept = farthest[j, t]
                    larger = kept if kept > carry1 else carry1
                    carry1 = carry1 if kept > carry1 else kept
                    kept = larger if larger > carry2 else carry2
                    carry2 = carry2 if larger > carry2 else larger
                    larger = kept if kept > carry3 else carry3
                    carry3 = carry3 if kept > carry3 else kept
                    farthest[j, t] = larger if larger > carry4 else carry4
                    carry4 = carry4 if larger > carry4 else larger
        for s in range(span):
            p = start + np.uint64(s)
            if not valid[p]:
                continue
            n = near_count[s]
            points[i, 0], points[i, 1], points[i, 2] = x[p], y[p], z[p]
            kept = total[s]
            for j in range(n - k):  # the k nearest: the n - k farthest out, largest first
                kept -= farthest[j, s]
            if n:
                spread[i] = kept / min(n, k)
            i += 1
    return points, spread


def backproject(depth: np.ndarray, intrinsics: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) camera-frame points of the valid depth pixels (inside `mask` when given)."""
    valid = np.isfinite(depth) & (depth > 0)
    if mask is not None:
        valid &= mask
    v, u = np.nonzero(valid)
    z = depth[v, u].astype(np.float64)
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    return np.column_stack(((u - cx) * z / fx, (v - cy) * z / fy, z))
