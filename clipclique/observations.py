"""Detections + an RGB-D frame -> observed ellipsoids in the camera frame, with their image crops.

Each detection mask is eroded (depth at object edges mixes fore- and background), its valid
depth back-projected with the frame's intrinsics, outliers cut (neighbours from the image
window) and a PCA box fitted (`geometry.fit_ellipsoid_depth`). Detections that cannot give a trustworthy ellipsoid are dropped
and counted by reason, so a run can say where objects were lost; nothing becomes NaN.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from clipclique.config import ObservationParams
from clipclique.encoders import Crop, Encoder
from clipclique.geometry import fit_ellipsoid_depth, stack_ellipsoids
from clipclique.types import Camera, Detections, Frame, Observations

DROP_REASONS = ("tiny mask", "border sliver", "invalid depth", "degenerate fit")


@dataclass
class Extraction:
    """Observations of one frame (embeddings not yet computed) and what the encoder needs."""

    observations: Observations
    crops: list[Crop]  # one per observation: its box of the image (and of the instance image), border-cut or not
    dropped: dict[str, int]  # detections lost, by reason (keys: DROP_REASONS)


def extract_observations(frame: Frame, detections: Detections, params: ObservationParams = ObservationParams()) -> Extraction:
    """Fit one camera-frame ellipsoid per usable detection."""
    height, width = frame.depth.shape
    dropped: Counter[str] = Counter({reason: 0 for reason in DROP_REASONS})
    fits, kept, truncated, areas = [], [], [], []
    for k, (mask, box) in enumerate(zip(detections.masks, detections.boxes)):
        window = _masked_window(frame.depth, frame.intrinsics, mask, box, params)
        pixels, in_band = ((window.pixels, window.in_band) if detections.masks_in_boxes
                           else mask_pixels(mask, params.border_px))
        if pixels < params.min_mask_pixels:
            dropped["tiny mask"] += 1
            continue
        if in_band > params.max_border_fraction * pixels:
            dropped["border sliver"] += 1
            continue
        if window.with_depth < params.fit.min_points:
            dropped["invalid depth"] += 1
            continue
        fit = fit_ellipsoid_depth(window.depth, window.intrinsics, window.mask, params.fit)
        if fit is None:
            dropped["degenerate fit"] += 1
            continue
        fits.append(fit)
        kept.append(k)
        truncated.append(in_band > 0)
        areas.append(pixels)
    index = np.array(kept, int)
    observations = Observations(stack_ellipsoids(fits), detections.class_ids[index], None,
                                detections.instance_ids[index], index, detections.boxes[index].astype(float),
                                np.array(areas, int), Camera(frame.intrinsics, width, height, params.max_depth),
                                scores=detections.scores[index].astype(float))
    crops = [Crop(crop(frame.rgb, detections.boxes[k]),
                  None if frame.instances is None else crop(frame.instances, detections.boxes[k]), cut)
             for k, cut in zip(kept, truncated)]
    return Extraction(observations, crops, dict(dropped))


def mask_pixels(mask: np.ndarray, band: int) -> tuple[int, int]:
    """(pixels of `mask`, those within `band` pixels of the image border): numpy's count over the
    whole mask (it is faster than a loop), the band's in compiled code."""
    return int(np.count_nonzero(mask)), _band_pixels(mask, band)


@njit(cache=True)
def _band_pixels(mask: np.ndarray, band: int) -> int:
    """Pixels of `mask` within `band` pixels of the image border, counted over the band alone."""
    height, width = mask.shape
    if 2 * band >= min(height, width):
        return np.count_nonzero(mask)
    count = 0
    for v in range(height):
        if v < band or v >= height - band:
            for u in range(width):
                count += mask[v, u]
        else:
            for u in range(band):
                count += mask[v, u] + mask[v, width - band + u]
    return count


class Window(NamedTuple):
    """A detection's box of the frame, widened by the erosion's reach, as the fit reads it."""

    depth: np.ndarray  # the depth, 0 beyond `max_depth`
    intrinsics: np.ndarray  # the camera's, shifted to the window's origin
    mask: np.ndarray  # the eroded mask (the mask itself where too little survives)
    with_depth: int  # pixels of `mask` with a positive depth
    pixels: int  # pixels of the mask in the window (all of them where the mask lies inside its box)
    in_band: int  # ... and of those, within the border band (`ObservationParams.border_px`) of the image


def _masked_window(depth: np.ndarray, intrinsics: np.ndarray, mask: np.ndarray, box: np.ndarray,
                   params: ObservationParams) -> Window:
    """The detection's `Window`: erosion over the box, not the image; depth beyond `params.max_depth` reads
    as missing (0)."""
    height, width = depth.shape
    pad = params.erode_px + 1
    x0, y0 = max(math.floor(box[0]) - pad, 0), max(math.floor(box[1]) - pad, 0)
    x1, y1 = min(math.ceil(box[2]) + pad, width), min(math.ceil(box[3]) + pad, height)
    window_mask, window_depth, with_depth, pixels, in_band = _window_pixels(
        mask[y0:y1, x0:x1], depth[y0:y1, x0:x1], params.erode_px, params.min_mask_pixels, params.max_depth,
        (y0, x0, height, width, params.border_px))
    shifted = intrinsics.copy()
    shifted[:2, 2] -= (x0, y0)
    return Window(window_depth, shifted, window_mask, with_depth, pixels, in_band)


@njit(cache=True)
def _window_pixels(mask: np.ndarray, depth: np.ndarray, erode_px: int, min_pixels: int, max_depth: float,
                   placed: tuple[int, int, int, int, int]) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """A detection's window prepared in compiled code, without scipy's and numpy's per-call overhead.

    Returns the mask eroded `erode_px` times by the 4-neighbour cross with pixels beyond the edge
    unset (`scipy.ndimage.binary_erosion`'s), or the mask itself where fewer than `min_pixels`
    survive; the depth with values beyond `max_depth` (and NaN) set to 0; how many pixels of
    the returned mask have a positive depth; and the window's mask pixels, and those in the image's
    border band, where `placed` = (window top, left, image height, width, band) (`mask_pixels` of
    the whole mask where it lies in the window). The window is copied once into flat arrays indexed by
    unsigned integers, so that the compiler vectorizes the erosion's rows.
    """
    top, left, image_height, image_width, band = placed
    everywhere = 2 * band >= min(image_height, image_width)  # the band covers the image (`_band_pixels`)
    height, width = mask.shape
    size = height * width
    given = np.empty(size, np.bool_)
    cut = np.empty((height, width), depth.dtype)
    flat_cut = cut.reshape(size)
    pixels, in_band = 0, 0
    for v in range(height):
        row = np.uint64(v * width)
        row_in_band = everywhere or top + v < band or top + v >= image_height - band
        for u in range(width):
            inside = mask[v, u]
            given[row + np.uint64(u)] = inside
            pixels += inside
            in_band += inside and (row_in_band or left + u < band or left + u >= image_width - band)
            value = depth[v, u]
            flat_cut[row + np.uint64(u)] = value if value <= max_depth else 0.0
    eroded = given
    for _ in range(erode_px):
        previous, eroded = eroded, np.zeros(size, np.bool_)
        for v in range(1, height - 1):
            row = np.uint64(v * width)
            above, below = row - np.uint64(width), row + np.uint64(width)
            for u in range(1, width - 1):
                t = np.uint64(u)
                eroded[row + t] = (previous[row + t] & previous[above + t] & previous[below + t]
                                   & previous[row + t - np.uint64(1)] & previous[row + t + np.uint64(1)])
    survivors = 0
    for t in range(size):
        survivors += eroded[t]
    if survivors < min_pixels:
        eroded = given
    with_depth = 0
    for t in range(size):
        with_depth += eroded[t] and flat_cut[t] > 0
    return eroded.reshape((height, width)), cut, with_depth, pixels, in_band


def crop(image: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The pixels of an xyxy box, clipped to the image, at least one pixel."""
    height, width = image.shape[:2]
    x0, y0 = min(max(math.floor(box[0]), 0), width - 1), min(max(math.floor(box[1]), 0), height - 1)
    x1, y1 = min(max(math.ceil(box[2]), x0 + 1), width), min(max(math.ceil(box[3]), y0 + 1), height)
    return image[y0:y1, x0:x1]


def embed(extraction: Extraction, encoder: Encoder | None) -> Observations:
    """The observations with CLIP image embeddings of their crops (None without an encoder)."""
    observations = extraction.observations
    if encoder is not None:
        observations.image_embeddings = encoder.encode_images(extraction.crops)
    return observations
