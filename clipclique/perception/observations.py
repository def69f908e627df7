"""Detections + an RGB-D frame -> observed ellipsoids in the camera frame, with their image crops.

Each detection mask is eroded (depth at object edges mixes fore- and background), its valid
depth back-projected with the frame's intrinsics, outliers cut (neighbours from the image
window) and a PCA box fitted (`ellipsoids.fit_ellipsoid_depth`). Detections that cannot give a trustworthy ellipsoid are
dropped and counted by reason, so a run can say where objects were lost; nothing becomes NaN.
"""

from __future__ import annotations

import enum
import functools
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from clipclique.config import ObservationParams
from clipclique.perception.depth import _neighbour_pass
from clipclique.perception.ellipsoids import Oriented, _box_parts, finished_box, fit_ellipsoid_depth, stack_ellipsoids
from clipclique.perception.encoders import Crop, Encoder
from clipclique.types import Camera, Detections, Frame, Observations

DROP_REASONS = ("tiny mask", "border sliver", "invalid depth", "degenerate fit")


@dataclass
class Extraction:
    """Observations of one frame (embeddings not yet computed) and what the encoder needs."""

    observations: Observations
    crops: list[Crop]  # one per observation: its box of the image (and of the instance image), border-cut or not
    dropped: dict[str, int]  # detections lost, by reason (keys: DROP_REASONS)


def extract_observations(frame: Frame, detections: Detections,
                         params: ObservationParams = ObservationParams()) -> Extraction:
    """Fit one camera-frame ellipsoid per usable detection: the whole frame in one compiled pass (`_frame_pass`)
    where its input is plain, a detection the pass leaves to numpy (`Oriented.NOT_FINITE`) and every detection
    of an unusual input (`_plain`) one at a time (`_fit_detection`)."""
    height, width = frame.depth.shape
    dropped: Counter[str] = Counter({reason: 0 for reason in DROP_REASONS})
    fits, kept, truncated, areas = [], [], [], []
    passed = _frame_pass(frame, detections, params) if _plain(frame, detections) else None
    left, boxed = int(_Outcome.LEFT), int(_Outcome.BOXED)  # plain integers: an enum member's lookup is slow
    # the pass's numbers as Python integers, read once (not a numpy scalar and an enum comparison per detection)
    outcomes = [left] * len(detections.masks) if passed is None else passed.outcomes.tolist()
    pixels_of, in_band_of, oriented = (None, None, None) if passed is None else (
        passed.pixels.tolist(), passed.in_band.tolist(), passed.oriented.tolist())
    for k, (mask, box) in enumerate(zip(detections.masks, detections.boxes)):
        outcome = outcomes[k]
        if outcome == left:
            reason, fit, pixels, in_band = _fit_detection(frame, mask, box, detections.masks_in_boxes, params)
        else:
            pixels, in_band, fit = pixels_of[k], in_band_of[k], None
            if outcome == boxed:
                fit = finished_box(oriented[k], passed.axes[k], passed.rotations[k], passed.means[k],
                                   passed.middles[k], passed.eigenvectors[k])
            reason = DROP_REASONS[outcome - 1] if outcome != boxed else None if fit is not None else "degenerate fit"
        if reason is not None:
            dropped[reason] += 1
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
    corners = np.asarray(detections.boxes).tolist()  # Python numbers: `crop`'s floor and ceil without numpy scalars
    crops = [Crop(crop(frame.rgb, corners[k]), None if frame.instances is None else crop(frame.instances, corners[k]),
                  cut)
             for k, cut in zip(kept, truncated)]
    return Extraction(observations, crops, dict(dropped))


def _fit_detection(frame: Frame, mask: np.ndarray, box: np.ndarray, in_box: bool, params: ObservationParams
                   ) -> tuple[str | None, tuple[np.ndarray, np.ndarray, np.ndarray] | None, int, int]:
    """(the reason it is dropped or None, its fit, its mask's pixels, those in the border band) of one detection."""
    window = _masked_window(frame.depth, frame.intrinsics, mask, box, params)
    pixels, in_band = (window.pixels, window.in_band) if in_box else mask_pixels(mask, params.border_px)
    if pixels < params.min_mask_pixels:
        return "tiny mask", None, pixels, in_band
    if in_band > params.max_border_fraction * pixels:
        return "border sliver", None, pixels, in_band
    if window.with_depth < params.fit.min_points:
        return "invalid depth", None, pixels, in_band
    fit = fit_ellipsoid_depth(window.depth, window.intrinsics, window.mask, params.fit)
    return None if fit is not None else "degenerate fit", fit, pixels, in_band


class _Outcome(enum.IntEnum):
    """What `_frame_pass` made of a detection."""

    BOXED = 0  # fitted up to its centre (`ellipsoids._box_parts`): its `Oriented` value says the rest
    TINY_MASK = 1  # dropped, for DROP_REASONS[value - 1]
    BORDER_SLIVER = 2
    INVALID_DEPTH = 3
    DEGENERATE_FIT = 4  # too few points
    LEFT = 5  # to `_fit_detection`: a scatter that is not finite, which numpy's `eigh` decides


class _Passed(NamedTuple):
    """`_frame_pass`'s answer, per detection (the box parts meaningful where the outcome is BOXED)."""

    outcomes: np.ndarray  # (K,) `_Outcome` values
    pixels: np.ndarray  # (K,) the mask's pixels
    in_band: np.ndarray  # (K,) ... within the image's border band
    oriented: np.ndarray  # (K,) `Oriented` values, then `_box_parts`' (K, 3) axes, (K, 3, 3) rotations, ...
    axes: np.ndarray
    rotations: np.ndarray
    means: np.ndarray
    middles: np.ndarray
    eigenvectors: np.ndarray


def _plain(frame: Frame, detections: Detections) -> bool:
    """Whether `_frame_pass` takes the input: float64 intrinsics (the window's shifted in their own type),
    masks the depth's size and boxes whose corners `math.floor` makes small integers (an unusual input goes
    detection by detection, where it fails or not as it always has)."""
    boxes = np.asarray(detections.boxes)
    return (frame.intrinsics.dtype == np.float64 and frame.intrinsics.shape == (3, 3)
            and detections.masks.ndim == 3 and detections.masks.shape[1:] == frame.depth.shape
            and boxes.shape == (len(detections.masks), 4) and bool((np.abs(boxes) < 2.0**52).all()))


def _frame_pass(frame: Frame, detections: Detections, params: ObservationParams) -> _Passed:
    """`_fit_detection` of every detection, in one compiled call (`_compiled_frame_pass`)."""
    fit = params.fit
    radius = math.ceil((math.sqrt(fit.outlier_neighbors + 1) - 1) / 2)  # as `fit_ellipsoid_depth`'s
    run = _compiled_frame_pass(fit.outlier_neighbors, radius)
    return _Passed(*run(detections.masks, np.asarray(detections.boxes, np.float64), frame.depth, frame.intrinsics,
                        not detections.masks_in_boxes, params.erode_px, params.min_mask_pixels, params.max_depth,
                        params.border_px, params.max_border_fraction, fit.min_points, fit.max_points,
                        fit.outlier_std_ratio, fit.min_axis))


@functools.cache
def _compiled_frame_pass(k: int, radius: int):
    """The compiled frame pass for `k` neighbours within `radius` pixels, compiled in as constants (as
    `depth._depth_points` compiles them; a closure over integers alone, which numba's cache finds again, named
    apart per pair as there)."""

    def frame_pass(masks, boxes, depth, intrinsics, whole, erode_px, min_pixels, max_depth, border_px,
                   max_border_fraction, min_points, max_points, ratio, min_axis):
        """`_fit_detection` of each detection, step for step: `_masked_window`, the drops, `fit_ellipsoid_depth`
        and `_box_parts`, the same compiled passes on the same arrays (numpy's centre product is left to
        `finished_box`). `whole`: count the whole masks (`mask_pixels`), not their windows."""
        count = len(boxes)
        height, width = depth.shape
        outcomes = np.full(count, _Outcome.LEFT.value, np.int64)
        pixels_of, in_band_of, oriented = (np.zeros(count, np.int64), np.zeros(count, np.int64),
                                           np.zeros(count, np.int64))
        axes, means, middles = np.zeros((count, 3)), np.zeros((count, 3)), np.zeros((count, 3))
        rotations, eigenvectors = np.zeros((count, 3, 3)), np.zeros((count, 3, 3))
        pad = erode_px + 1
        for j in range(count):
            mask = masks[j]
            x0, y0 = max(math.floor(boxes[j, 0]) - pad, 0), max(math.floor(boxes[j, 1]) - pad, 0)
            x1, y1 = min(math.ceil(boxes[j, 2]) + pad, width), min(math.ceil(boxes[j, 3]) + pad, height)
            window_mask, window_depth, with_depth, pixels, in_band = _window_pixels(
                mask, depth, (y0, y1, x0, x1), erode_px, min_pixels, max_depth, border_px)
            if whole:
                pixels, in_band = np.count_nonzero(mask), _band_pixels(mask, border_px)
            pixels_of[j], in_band_of[j] = pixels, in_band
            if pixels < min_pixels:
                outcomes[j] = _Outcome.TINY_MASK.value
                continue
            if in_band > max_border_fraction * pixels:
                outcomes[j] = _Outcome.BORDER_SLIVER.value
                continue
            if with_depth < min_points:
                outcomes[j] = _Outcome.INVALID_DEPTH.value
                continue
            shifted = intrinsics.copy()
            shifted[0, 2] -= x0
            shifted[1, 2] -= y0
            stride = max(1, math.ceil(math.sqrt(np.count_nonzero(window_mask) / max_points)))
            if stride > 1:
                shifted[:2] /= stride
            points, spread = _neighbour_pass(window_depth[::stride, ::stride], window_mask[::stride, ::stride], shifted,
                                             k, radius)  # inlined once: half the compile time
            if len(points) < min_points:
                outcomes[j] = _Outcome.DEGENERATE_FIT.value
                continue
            parts = _box_parts(points, spread, ratio, min_points, min_axis)
            if parts[0] == Oriented.NOT_FINITE.value:
                continue  # LEFT
            outcomes[j], oriented[j] = _Outcome.BOXED.value, parts[0]
            axes[j], rotations[j], means[j], middles[j], eigenvectors[j] = (parts[1], parts[2], parts[3], parts[4],
                                                                            parts[5])
        return outcomes, pixels_of, in_band_of, oriented, axes, rotations, means, middles, eigenvectors

    frame_pass.__qualname__ = f"frame_pass_k{k}_r{radius}"  # cache files of its own (`depth._depth_points`)
    return njit(cache=True)(frame_pass)


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
        mask, depth, (y0, y1, x0, x1), params.erode_px, params.min_mask_pixels, params.max_depth, params.border_px)
    shifted = intrinsics.copy()
    shifted[:2, 2] -= (x0, y0)
    return Window(window_depth, shifted, window_mask, with_depth, pixels, in_band)


@njit(cache=True)
def _window_pixels(mask: np.ndarray, depth: np.ndarray, bounds: tuple[int, int, int, int], erode_px: int,
                   min_pixels: int, max_depth: float, band: int) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """A detection's window prepared in compiled code, without scipy's and numpy's per-call overhead.

    Returns, for the window `bounds` = (top, bottom, left, right) of the image (`mask[top:bottom, left:right]`
    and the same of `depth`), the mask eroded `erode_px` times by the 4-neighbour cross with pixels beyond the edge
    unset (`scipy.ndimage.binary_erosion`'s), or the mask itself where fewer than `min_pixels`
    survive; the depth with values beyond `max_depth` (and NaN) set to 0; how many pixels of
    the returned mask have a positive depth; and the window's mask pixels, and those within `band` pixels of
    the image's border (`mask_pixels` of the whole mask where it lies in the window). The window is read from
    the whole image's rows and copied once into flat arrays, all indexed by unsigned integers, so that the
    compiler vectorizes the rows; the band is counted afterwards, over its rows and columns alone.
    """
    image_height, image_width = depth.shape
    top, left = bounds[0], bounds[2]
    bottom = min(bounds[1], image_height, mask.shape[0])  # as slicing both clips the window
    right = min(bounds[3], image_width, mask.shape[1])
    height, width = max(bottom - top, 0), max(right - left, 0)
    size = height * width
    given = np.empty(size, np.bool_)
    cut = np.empty((height, width), depth.dtype)
    flat_cut = cut.reshape(size)
    pixels = 0
    for v in range(height):
        row, mask_row, depth_row = np.uint64(v * width), mask[top + v], depth[top + v]
        for u in range(width):
            t, at = np.uint64(u), np.uint64(left + u)
            inside = mask_row[at]
            given[row + t] = inside
            pixels += inside
            value = depth_row[at]
            flat_cut[row + t] = value if value <= max_depth else 0.0
    in_band = 0
    everywhere = 2 * band >= min(image_height, image_width)  # the band covers the image (`_band_pixels`)
    for v in range(height):
        row = np.uint64(v * width)
        if everywhere or top + v < band or top + v >= image_height - band:
            for u in range(width):
                in_band += given[row + np.uint64(u)]
        else:  # the columns left of `band` and from `image_width - band` on (apart: the band is narrow)
            for u in range(min(width, band - left)):
                in_band += given[row + np.uint64(u)]
            for u in range(max(image_width - band - left, 0), width):
                in_band += given[row + np.uint64(u)]
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
        with_depth += eroded[t] & (flat_cut[t] > 0)
    return eroded.reshape((height, width)), cut, with_depth, pixels, in_band


def crop(image: np.ndarray, box: Sequence[float] | np.ndarray) -> np.ndarray:
    """The pixels of an xyxy box (numbers or an array), clipped to the image, at least one pixel."""
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
