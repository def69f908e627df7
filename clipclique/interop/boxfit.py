"""A detection box without a mask -> the pixels of its object, from the depth image alone.

Published detection files (OA-SLAM, VOOM, GOReloc) hold boxes, not masks. The segmentation,
documented in docs/formats.md ("Box-only detections"):
1. the ellipse inscribed in the box (VOOM's fitted ellipse when the file has one): the box's
   corners are mostly background;
2. valid depth there (0 < z <= max depth);
3. border rejection: the band just outside the box (`band_fraction` of its smaller side, at
   least `min_band_px`) is background; when its points lie on one plane (a table top under a
   book, a wall behind a monitor: median residual under `plane_fit_m`), pixels within
   `plane_reject_m` of that plane are background too;
4. the nearest dominant depth mode: a histogram of the remaining depths in `bin_m` bins, each
   pixel weighted by its closeness to the ellipse's centre (1 - r^2: an object fills its box's
   middle, occluders and neighbours its edges), smoothed; the modes holding at least
   `min_mode_share` of the largest one; the nearest kept (an object sits in front of what its
   box also shows);
5. background rejection: only depths from `front_m` in front of the mode to the object's likely
   depth extent behind it (its smaller lateral size, from the box and the mode's depth, at least
   `min_extent_m`).
The result is a mask for `clipclique.observations.extract_observations`, which fits it as any.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BoxSegmentation:
    bin_m: float = 0.02  # depth histogram bin
    smooth_bins: int = 3  # moving-average window over the bins
    min_mode_share: float = 0.3  # a mode counts when it holds this share of the largest
    front_m: float = 0.04  # depths kept in front of the mode
    min_extent_m: float = 0.05  # depths kept behind the mode, at least
    band_fraction: float = 0.15  # the background band outside the box, of its smaller side
    min_band_px: int = 3
    plane_fit_m: float = 0.01  # the band is a plane when its median residual is under this
    plane_reject_m: float = 0.015  # ... and pixels this close to it are background
    ellipse_scale: float = 1.0  # the inscribed ellipse scaled by this (sqrt 2 reaches the box's corners)
    grow: bool = False  # keep the depth-continuous surfaces holding the mode instead of a depth band
    jump_ratio: float = 0.03  # a depth step between neighbours above this fraction of the depth is an edge
    max_depth: float = 8.0


def ellipse_region(box: np.ndarray, shape: tuple[int, int], ellipse: np.ndarray | None = None,
                   scale: float = 1.0) -> np.ndarray:
    """(H, W) bool: the ellipse inscribed in the xyxy `box`, or VOOM's `[cx, cy, width, height, angle_rad]`
    (full axis lengths; the angle turns the width axis from +x towards +y)."""
    height, width = shape
    if ellipse is None:
        cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
        a, b, angle = max((box[2] - box[0]) / 2, 0.5), max((box[3] - box[1]) / 2, 0.5), 0.0
    else:
        cx, cy, a, b, angle = ellipse[0], ellipse[1], max(ellipse[2] / 2, 0.5), max(ellipse[3] / 2, 0.5), ellipse[4]
    a, b = a * scale, b * scale
    reach = max(a, b)
    x0, x1 = max(math.floor(cx - reach), 0), min(math.ceil(cx + reach) + 1, width)
    y0, y1 = max(math.floor(cy - reach), 0), min(math.ceil(cy + reach) + 1, height)
    out = np.zeros(shape, bool)
    if x0 >= x1 or y0 >= y1:
        return out
    v, u = np.mgrid[y0:y1, x0:x1]
    du, dv = u + 0.5 - cx, v + 0.5 - cy  # pixel centres
    along = du * math.cos(angle) + dv * math.sin(angle)
    across = -du * math.sin(angle) + dv * math.cos(angle)
    out[y0:y1, x0:x1] = (along / a) ** 2 + (across / b) ** 2 <= 1.0
    if ellipse is None:  # never beyond the box
        out[:, :max(math.floor(box[0]), 0)] = out[:, math.ceil(box[2]):] = False
        out[:max(math.floor(box[1]), 0)] = out[math.ceil(box[3]):] = False
    return out


def nearest_mode(depths: np.ndarray, weights: np.ndarray, params: BoxSegmentation) -> float | None:
    """The depth of the nearest dominant mode of `depths` (metres, weighted), None when there are none."""
    if len(depths) == 0:
        return None
    low = float(depths.min())
    bins = max(1, math.ceil((float(depths.max()) - low) / params.bin_m) + 1)
    counts = np.bincount(((depths - low) / params.bin_m).astype(np.int64), weights, minlength=bins)
    smooth = np.convolve(counts, np.ones(params.smooth_bins) / params.smooth_bins, mode="same")
    padded = np.r_[-1.0, smooth, -1.0]
    peaks = np.flatnonzero((padded[1:-1] >= padded[:-2]) & (padded[1:-1] > padded[2:]))
    dominant = peaks[smooth[peaks] >= params.min_mode_share * smooth.max()]
    return low + (dominant[0] + 0.5) * params.bin_m


def _points(depth: np.ndarray, intrinsics: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    z = depth[rows, cols].astype(np.float64)
    return np.column_stack(((cols - intrinsics[0, 2]) * z / intrinsics[0, 0], (rows - intrinsics[1, 2]) * z / intrinsics[1, 1], z))


def background_plane(depth: np.ndarray, intrinsics: np.ndarray, box: np.ndarray,
                     params: BoxSegmentation) -> tuple[np.ndarray, float] | None:
    """(unit normal, offset) of the plane the band around the box lies on, None when it is not one plane."""
    height, width = depth.shape
    band = max(params.min_band_px, round(params.band_fraction * min(box[2] - box[0], box[3] - box[1])))
    x0, y0 = max(math.floor(box[0]) - band, 0), max(math.floor(box[1]) - band, 0)
    x1, y1 = min(math.ceil(box[2]) + band, width), min(math.ceil(box[3]) + band, height)
    ring = np.zeros((y1 - y0, x1 - x0), bool)
    ring[:, :] = True
    ring[max(math.floor(box[1]) - y0, 0):math.ceil(box[3]) - y0, max(math.floor(box[0]) - x0, 0):math.ceil(box[2]) - x0] = False
    window = depth[y0:y1, x0:x1]
    ring &= (window > 0) & (window <= params.max_depth)
    rows, cols = np.nonzero(ring)
    if len(rows) < 20:
        return None
    points = _points(depth, intrinsics, rows + y0, cols + x0)
    centre = np.median(points, axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[2]
    residual = np.abs((points - centre) @ normal)
    if np.median(residual) > params.plane_fit_m:
        return None
    inliers = residual <= 2 * params.plane_fit_m  # one refit on the points near the plane
    centre = points[inliers].mean(axis=0)
    _, _, vt = np.linalg.svd(points[inliers] - centre, full_matrices=False)
    return vt[2], float(vt[2] @ centre)


def box_mask(depth: np.ndarray, intrinsics: np.ndarray, box: np.ndarray, ellipse: np.ndarray | None = None,
             params: BoxSegmentation = BoxSegmentation()) -> np.ndarray:
    """(H, W) bool: the pixels of a box-only detection's object (module docstring); empty when no depth."""
    region = ellipse_region(box, depth.shape, ellipse, params.ellipse_scale)
    valid = region & (depth > 0) & (depth <= params.max_depth)
    rows, cols = np.nonzero(valid)
    if len(rows) == 0:
        return valid
    plane = background_plane(depth, intrinsics, box, params)
    if plane is not None:
        normal, offset = plane
        near = np.abs(_points(depth, intrinsics, rows, cols) @ normal - offset) <= params.plane_reject_m
        if near.mean() < 0.9:  # a plane covering (nearly) the whole box is the object's own face, not background
            valid[rows[near], cols[near]] = False
            rows, cols = rows[~near], cols[~near]
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    radius = ((cols + 0.5 - cx) / max((box[2] - box[0]) / 2, 0.5)) ** 2 + ((rows + 0.5 - cy) / max((box[3] - box[1]) / 2, 0.5)) ** 2
    mode = nearest_mode(depth[rows, cols].astype(np.float64), np.clip(1.0 - radius, 0.05, 1.0), params)
    if mode is None:
        return valid
    side_px = min(box[2] - box[0], box[3] - box[1])
    if params.grow:
        return _continuous(depth, valid, mode, params) & (depth <= mode + max(box[2] - box[0], box[3] - box[1]) * mode / intrinsics[0, 0])
    extent = max(params.min_extent_m, side_px * mode / intrinsics[0, 0])
    return valid & (depth >= mode - params.front_m) & (depth <= mode + extent)


def _continuous(depth: np.ndarray, valid: np.ndarray, mode: float, params: BoxSegmentation) -> np.ndarray:
    """The pixels of `valid` joined to the mode's pixels without a depth step (an edge) between neighbours."""
    from scipy import ndimage

    z = np.where(valid, depth, 0.0).astype(np.float64)
    limit = params.jump_ratio * np.maximum(z, 1e-6)
    edge = np.zeros_like(valid)
    step_x = np.abs(np.diff(z, axis=1)) > np.minimum(limit[:, 1:], limit[:, :-1])
    step_y = np.abs(np.diff(z, axis=0)) > np.minimum(limit[1:], limit[:-1])
    edge[:, 1:] |= step_x
    edge[:, :-1] |= step_x
    edge[1:] |= step_y
    edge[:-1] |= step_y
    labels, count = ndimage.label(valid & ~edge)
    seeds = labels[(np.abs(z - mode) <= params.bin_m) & (labels > 0)]
    if count == 0 or len(seeds) == 0:
        return valid & (np.abs(z - mode) <= params.bin_m)
    sizes = np.bincount(seeds, minlength=count + 1)
    return np.isin(labels, np.flatnonzero(sizes >= params.min_mode_share * sizes.max()))
