"""Observations from synthetic RGB-D: a ray-traced sphere, plus every way a detection can be dropped."""

from __future__ import annotations

import numpy as np
import pytest

from clipclique.config import FitParams
from clipclique.perception.depth import _depth_points
from clipclique.perception.detectors import mask_boxes
from clipclique.perception.observations import (
    ObservationParams,
    _window_pixels,
    crop,
    embed,
    extract_observations,
    mask_pixels,
)
from clipclique.sim.encoder import SimulatedClipEncoder
from clipclique.types import Detections, Frame, Pose

K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
SPHERE_CENTER, SPHERE_RADIUS = np.array([0.2, -0.1, 2.0]), 0.3


def sphere_frame() -> tuple[Frame, np.ndarray]:
    """Depth of a sphere in front of a wall at 4 m; returns the frame and the sphere's mask."""
    v, u = np.mgrid[:240, :320]
    rays = np.stack(((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((240, 320))), axis=-1)
    # |z * ray - c|^2 = r^2, nearest root in z
    a = (rays**2).sum(-1)
    b = -2 * rays @ SPHERE_CENTER
    c = SPHERE_CENTER @ SPHERE_CENTER - SPHERE_RADIUS**2
    disc = b**2 - 4 * a * c
    mask = disc > 0
    depth = np.full((240, 320), 4.0)
    depth[mask] = (-b[mask] - np.sqrt(disc[mask])) / (2 * a[mask])
    rgb = np.random.default_rng(0).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    return Frame(0, 0.0, rgb, depth.astype(np.float32), K, Pose.identity()), mask


def detections_of(masks: list[np.ndarray], instance_ids: list[int]) -> Detections:
    stack = np.stack(masks)
    count = len(masks)
    return Detections(stack, mask_boxes(stack), np.arange(count) % 2, np.ones(count), np.array(instance_ids))


def test_sphere_becomes_a_camera_frame_ellipsoid():
    frame, mask = sphere_frame()
    extraction = extract_observations(frame, detections_of([mask], [5]))
    observations = extraction.observations
    assert len(observations) == 1 and extraction.dropped == dict.fromkeys(extraction.dropped, 0)
    center = observations.ellipsoids.centers[0]
    np.testing.assert_allclose(center[:2], SPHERE_CENTER[:2], atol=0.03)
    assert SPHERE_CENTER[2] - SPHERE_RADIUS < center[2] < SPHERE_CENTER[2]  # only the near cap is seen
    axes = observations.ellipsoids.axes[0]
    np.testing.assert_allclose(axes[:2], SPHERE_RADIUS, atol=0.04)  # the silhouette spans the radius
    assert axes[2] < 0.2  # the cap is shallow
    assert observations.instance_ids.tolist() == [5] and observations.detection_index.tolist() == [0]
    pixels = extraction.crops[0].pixels
    assert not extraction.crops[0].truncated and extraction.crops[0].instances is None
    assert pixels.shape[2] == 3 and abs(pixels.shape[0] - 2 * 300 * 0.3 / 1.96) < 10


def test_bad_detections_are_dropped_by_reason_never_nan():
    frame, sphere = sphere_frame()
    frame.depth[sphere & (np.arange(320) < 175)[None]] = np.nan  # half the sphere without depth
    tiny = np.zeros_like(sphere)
    tiny[10:15, 100:105] = True
    sliver = np.zeros_like(sphere)
    sliver[50:200, 0:5] = True
    no_depth = np.zeros_like(sphere)
    no_depth[180:230, 200:260] = True
    frame.depth[no_depth] = 0.0
    flat = np.zeros_like(sphere)
    flat[20:80, 240:300] = True  # the wall: a plane, no thickness
    far = np.zeros_like(sphere)
    far[150:200, 20:80] = True
    frame.depth[far] = 12.0
    extraction = extract_observations(frame,
                                      detections_of([sphere, tiny, sliver, no_depth, flat, far], [1, 2, 3, 4, 5, 6]))
    assert extraction.dropped == {"tiny mask": 1, "border sliver": 1, "invalid depth": 2, "degenerate fit": 1}
    assert extraction.observations.detection_index.tolist() == [0]
    assert np.isfinite(extraction.observations.ellipsoids.centers).all()
    detections = detections_of([tiny, sphere], [2, 1])
    detections.scores = np.array([0.9, 0.42])
    kept = extract_observations(frame, detections).observations
    assert kept.scores.tolist() == [0.42] and kept.subset(np.array([0])).scores.tolist() == [0.42]  # the kept one's


def test_truncated_masks_are_kept_and_flagged():
    frame, sphere = sphere_frame()
    truncated = np.roll(sphere, -160, axis=1)  # shifted to the left border, depth rolled with it
    frame.depth = np.roll(frame.depth, -160, axis=1)
    extraction = extract_observations(frame, detections_of([truncated], [1]))
    assert len(extraction.observations) == 1 and [c.truncated for c in extraction.crops] == [True]


def test_crop_is_clipped_and_never_empty():
    rgb = np.zeros((10, 20, 3), np.uint8)
    assert crop(rgb, np.array([-5.0, 2.2, 7.5, 30.0])).shape == (8, 8, 3)
    assert crop(rgb, np.array([19.5, 9.5, 19.5, 9.5])).shape == (1, 1, 3)
    rng = np.random.default_rng(3)  # the box's numbers as a list (extract_observations') crop the same pixels
    image = rng.integers(0, 255, (10, 20, 3), np.uint8)
    for boxes in (rng.uniform(-4, 24, (200, 4)).astype(np.float32), rng.uniform(-4, 24, (200, 4)),
                  rng.integers(-4, 24, (200, 4)), np.array([[-0.0, -0.0, 0.0, 0.0], [3.0, 2.0, 3.0, 2.0]])):
        for box in boxes:
            assert np.shares_memory(crop(image, box.tolist()), image)
            assert crop(image, box.tolist()).__array_interface__ == crop(image, box).__array_interface__


def test_crops_carry_the_instance_image_in_their_box_and_the_simulated_encoder_reads_it():
    frame, mask = sphere_frame()
    frame.instances = np.where(mask, 5, 0).astype(np.int32)
    frame.instances[:, 200:] = np.where(mask[:, 200:], 5, 8)
    wall = np.zeros_like(mask)
    wall[0:100, 150:250] = True  # box 150..250 x 0..100
    extraction = extract_observations(frame, detections_of([mask, wall], [5, -1]))
    shown = extraction.crops[1]
    np.testing.assert_array_equal(shown.instances, frame.instances[0:100, 150:250])
    assert shown.pixels.shape[:2] == shown.instances.shape
    encoder = SimulatedClipEncoder({5: "a red ball", 8: "a white wall"})
    contents = dict(encoder.contents(shown))
    assert set(contents) == {None, "a red ball", "a white wall"}
    assert contents["a white wall"] == pytest.approx((~mask[:100, 200:250]).sum() / 100**2)
    assert contents["a red ball"] == pytest.approx(mask[:100, 150:250].mean())
    assert sum(contents.values()) == pytest.approx(1.0)
    assert dict(encoder.contents(extraction.crops[0]))["a red ball"] > 0.7


def test_embed_gives_each_crop_the_embedding_of_what_it_shows():
    frame, mask = sphere_frame()
    frame.instances = np.where(mask, 5, 0).astype(np.int32)
    bump = np.zeros_like(mask)
    bump[20:60, 20:60] = True  # a false detection: a bulge of the wall, no object of the instance image
    v, u = np.mgrid[20:60, 20:60]
    frame.depth[20:60, 20:60] -= 0.3 * np.clip(1 - ((v - 40) ** 2 + (u - 40) ** 2) / 400, 0, None)
    extraction = extract_observations(frame, detections_of([mask, bump], [5, -1]))
    encoder = SimulatedClipEncoder({5: "a red ball"})
    observations = embed(extraction, encoder)
    assert observations.image_embeddings.shape == (len(observations), 512) and len(observations) == 2
    text = encoder.encode_text(["a red ball"])[0]
    assert observations.image_embeddings[0] @ text > observations.image_embeddings[1] @ text + 0.05
    assert embed(extract_observations(frame, detections_of([mask], [5])), None).image_embeddings is None


def test_depth_fit_cuts_bled_background_and_agrees_with_the_point_fit():
    """A mask that bleeds onto the wall behind the sphere (every third pixel of a one-pixel ring,
    2 m behind) is cut by the image-window outlier filter, and only it: the fit equals the fit of
    the sphere's own pixels without a filter. On the clean mask the image-window filter and the
    KD-tree filter (the map builder's) give ellipsoids within 1 cm of each other."""
    from scipy import ndimage

    from clipclique.config import FitParams
    from clipclique.perception.depth import backproject
    from clipclique.perception.ellipsoids import fit_ellipsoid, fit_ellipsoid_depth

    frame, mask = sphere_frame()
    depth = frame.depth.astype(np.float64)
    ring = np.argwhere(ndimage.binary_dilation(mask) & ~mask)[::3]
    bled = mask.copy()
    bled[ring[:, 0], ring[:, 1]] = True  # depth there is the wall's, 4 m
    unfiltered = FitParams(outlier_std_ratio=1e9)
    for got, want in zip(fit_ellipsoid_depth(depth, K, bled), fit_ellipsoid_depth(depth, K, mask, unfiltered)):
        np.testing.assert_allclose(got, want, atol=1e-9)
    assert fit_ellipsoid_depth(depth, K, bled, unfiltered)[1][0] > 0.5  # unfiltered, the wall stretches the box
    by_image, by_tree = fit_ellipsoid_depth(depth, K, mask), fit_ellipsoid(backproject(depth, K, mask))
    np.testing.assert_allclose(by_image[0], by_tree[0], atol=0.01)
    np.testing.assert_allclose(by_image[1], by_tree[1], atol=0.01)


def reference_points(depth: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray, k: int,
                     radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Spelled out in numpy: the valid pixels' points and each one's mean distance to its k nearest
    within the image window."""
    v, u = np.nonzero(mask & np.isfinite(depth) & (depth > 0))
    z = depth[v, u].astype(float)
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    points = np.column_stack(((u - cx) * z / fx, (v - cy) * z / fy, z))
    grid = np.full((*depth.shape, 3), np.nan)
    grid[v, u] = points
    offsets = [(dv, du) for dv in range(-radius, radius + 1) for du in range(-radius, radius + 1) if dv or du]
    apart = np.full((len(points), len(offsets)), np.inf)
    for column, (dv, du) in enumerate(offsets):
        inside = (v + dv >= 0) & (v + dv < depth.shape[0]) & (u + du >= 0) & (u + du < depth.shape[1])
        distance = np.linalg.norm(grid[v[inside] + dv, u[inside] + du] - points[inside], axis=1)
        apart[inside, column] = np.where(np.isnan(distance), np.inf, distance)  # NaN: no valid pixel there
    apart = np.sort(apart, axis=1)[:, :k]
    counts = np.isfinite(apart).sum(axis=1)
    mean = np.where(np.isfinite(apart), apart, 0.0).sum(axis=1) / np.maximum(counts, 1)
    return points, np.where(counts > 0, mean, np.inf)


def reference_fit(frame: Frame, mask: np.ndarray, box: np.ndarray, params: ObservationParams):
    """The observation fit spelled out with scipy and numpy (the compiled path must agree):
    depth beyond max_depth missing, scipy erosion over the box window, every s-th row and column
    past max_points, each pixel's k nearest 3D neighbours among the valid pixels of its window."""
    from scipy import ndimage

    from clipclique.perception.ellipsoids import _box

    depth = np.where(frame.depth <= params.max_depth, frame.depth, 0.0)
    pad = params.erode_px + 1
    x0, y0 = max(int(np.floor(box[0])) - pad, 0), max(int(np.floor(box[1])) - pad, 0)
    x1, y1 = min(int(np.ceil(box[2])) + pad, depth.shape[1]), min(int(np.ceil(box[3])) + pad, depth.shape[0])
    window = mask[y0:y1, x0:x1]
    eroded = ndimage.binary_erosion(window, iterations=params.erode_px)
    use = eroded if eroded.sum() >= params.min_mask_pixels else window
    stride = max(1, int(np.ceil(np.sqrt(use.sum() / params.fit.max_points))))
    window_depth, use = depth[y0:y1:stride, x0:x1:stride], use[::stride, ::stride]
    intrinsics = K.copy()
    intrinsics[:2, 2] -= (x0, y0)
    intrinsics[:2] /= stride
    k = params.fit.outlier_neighbors
    points, spread = reference_points(window_depth, use, intrinsics, k, int(np.ceil((np.sqrt(k + 1) - 1) / 2)))
    return _box(points, spread, params.fit)


def test_compiled_fit_equals_the_reference_on_a_hand_made_frame():
    """Holes, NaN and too-far depth, a mask with a ragged edge, one subsampled past max_points and
    one whose erosion leaves too few pixels: the compiled window pass gives the reference's
    ellipsoids to 1e-9 (only the order of summation differs)."""
    from scipy import ndimage

    frame, sphere = sphere_frame()
    rng = np.random.default_rng(3)
    frame.depth += rng.normal(0, 0.004, frame.depth.shape).astype(np.float32)  # surface noise: outliers to cut
    frame.depth[rng.random(frame.depth.shape) < 0.05] = np.nan
    frame.depth[rng.random(frame.depth.shape) < 0.03] = 0.0
    frame.depth[:, 150:155] = 9.0  # beyond max_depth: missing
    ragged = sphere & (rng.random(sphere.shape) < 0.9)  # erosion eats far into a ragged mask
    wall = np.zeros_like(sphere)
    wall[30:100, 20:140] = True  # the wall at 4 m, given thickness by the noise
    thin = np.zeros_like(sphere)
    thin[160:230, 200:204] = True
    thin[195:199, 180:240] = True  # a cross of 4-pixel bars: erosion leaves fewer than min_mask_pixels
    params = ObservationParams(fit=FitParams(max_points=1000))
    assert ndimage.binary_erosion(sphere, iterations=2).sum() > 4 * 1000  # subsampled: every third row and column
    masks = [sphere, ragged, wall, thin]
    extraction = extract_observations(frame, detections_of(masks, [1, 2, 3, 4]), params)
    assert extraction.observations.detection_index.tolist() == [0, 1, 2, 3]
    assert ndimage.binary_erosion(thin, iterations=2).sum() < params.min_mask_pixels
    sparse = sphere & (rng.random(sphere.shape) < 0.1)  # pixels with fewer than k neighbours, some with none
    for mask in (ragged, sparse):
        ours = _depth_points(20, 2)(frame.depth, mask, K)
        theirs = reference_points(frame.depth, mask, K, 20, 2)
        np.testing.assert_allclose(ours[0], theirs[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(ours[1], theirs[1], rtol=0, atol=1e-12)
    assert np.isinf(theirs[1]).any() and np.isfinite(theirs[1]).any()
    for i, (mask, box) in enumerate(zip(masks, mask_boxes(np.stack(masks)))):
        center, axes, rotation = reference_fit(frame, mask, box, params)
        ellipsoids = extraction.observations.ellipsoids
        np.testing.assert_allclose(ellipsoids.centers[i], center, atol=1e-9)
        np.testing.assert_allclose(ellipsoids.axes[i], axes, atol=1e-9)
        np.testing.assert_allclose(ellipsoids.rotations[i], rotation, atol=1e-9)


def test_mask_pixels_counts_the_mask_and_its_border_band():
    """The one compiled pass counts what numpy counts, for bands of 0, 3 and wider than half the image."""
    rng = np.random.default_rng(5)
    mask = rng.random((40, 57)) < 0.3
    for band in (0, 3, 19, 20, 40):
        inner = np.zeros_like(mask)
        inner[band:40 - band, band:57 - band] = True
        assert mask_pixels(mask, band) == (np.count_nonzero(mask), np.count_nonzero(mask & ~inner))


def test_window_pixels_erode_and_cut_as_scipy_and_numpy():
    """The window pass: scipy's erosion (the mask itself when too little survives), depth beyond
    max_depth and NaN cut to 0 in the depth's own type, and the count of mask pixels with depth."""
    from scipy import ndimage

    rng = np.random.default_rng(6)
    depth = rng.uniform(0.0, 5.0, (30, 44)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = np.nan
    mask = np.zeros(depth.shape, bool)
    mask[3:27, 5:40] = rng.random((24, 35)) < 0.95
    for erode_px, min_pixels in ((0, 1), (1, 1), (2, 1), (2, 10_000)):
        eroded, cut, with_depth, _, _ = _window_pixels(mask, depth, (1, 30, 2, 44), erode_px, min_pixels, 4.0, 3)
        want = ndimage.binary_erosion(mask[1:, 2:], iterations=erode_px) if erode_px else mask[1:, 2:]
        want = want if want.sum() >= min_pixels else mask[1:, 2:]
        want_cut = np.where(depth[1:, 2:] <= 4.0, depth[1:, 2:], 0).astype(np.float32)
        assert np.array_equal(eroded, want) and cut.dtype == np.float32 and np.array_equal(cut, want_cut)
        assert with_depth == np.count_nonzero(want & (want_cut > 0))


@pytest.mark.parametrize("band", [0, 3, 6, 21, 22, 40])
def test_window_counts_are_mask_pixels_of_a_mask_inside_it(band):
    """The window pass counts a mask that lies inside the window as `mask_pixels` counts the whole mask:
    windows at the image's corners, its edges and inside, bands of 0 to wider than half the image."""
    rng = np.random.default_rng(band)
    depth = rng.uniform(0.5, 3.0, (44, 60)).astype(np.float32)
    for top, left, bottom, right in ((0, 0, 20, 25), (30, 41, 44, 60), (5, 9, 40, 52), (0, 0, 44, 60), (10, 0, 13, 60)):
        mask = np.zeros(depth.shape, bool)
        mask[top:bottom, left:right] = rng.random((bottom - top, right - left)) < 0.6
        *_, pixels, in_band = _window_pixels(mask, depth, (top, bottom, left, right), 1, 1, 8.0, band)
        assert (pixels, in_band) == mask_pixels(mask, band)


def test_masks_in_boxes_are_counted_in_their_windows_with_the_same_outcome():
    """Detections whose masks lie in their boxes are counted in the fit's windows, not over the whole image:
    the same observations, areas, drop counts and crops as counting the whole masks."""
    frame, sphere = sphere_frame()
    sliver, tiny, cut = np.zeros_like(sphere), np.zeros_like(sphere), np.zeros_like(sphere)
    sliver[0:6, 100:140] = True  # in the border band
    tiny[200:205, 300:305] = True
    cut[150:230, 0:60] = True  # truncated by the image's edge, most of it inside, on a bulge of the wall
    v, u = np.mgrid[150:230, 0:60]
    frame.depth[150:230, 0:60] = (3.0 + ((u - 30) ** 2 + (v - 190) ** 2) / 1500).astype(np.float32)
    detections = detections_of([sphere, sliver, tiny, cut], [1, 2, 3, 4])
    assert not detections.masks_in_boxes
    params = ObservationParams(min_mask_pixels=50)
    whole = extract_observations(frame, detections, params)
    detections.masks_in_boxes = True
    boxed = extract_observations(frame, detections, params)
    assert whole.dropped == boxed.dropped and whole.dropped["border sliver"] == 1 and whole.dropped["tiny mask"] == 1
    for field in ("centers", "axes", "rotations"):
        assert np.array_equal(getattr(whole.observations.ellipsoids, field),
                              getattr(boxed.observations.ellipsoids, field))
    assert np.array_equal(whole.observations.mask_areas, boxed.observations.mask_areas)
    assert [c.truncated for c in whole.crops] == [c.truncated for c in boxed.crops] == [False, True]


def each_detection(frame: Frame, detections: Detections, params: ObservationParams) -> list[tuple]:
    """Each detection fitted on its own, the path every detection took before the frame pass."""
    from clipclique.perception.observations import _fit_detection

    return [_fit_detection(frame, mask, box, detections.masks_in_boxes, params)
            for mask, box in zip(detections.masks, detections.boxes)]


def test_frame_pass_gives_each_detection_its_own_fit():
    """The compiled frame pass: the same drops (every reason), areas, border counts and ellipsoids (within rounding),
    as each detection on its own, whether the masks are counted whole or in their windows, subsampled or not;
    an input the pass does not take (float32 intrinsics) goes detection by detection."""
    from clipclique.perception.observations import _frame_pass, _Outcome, _plain

    frame, sphere = sphere_frame()
    rng = np.random.default_rng(8)
    frame.depth += rng.normal(0, 0.004, frame.depth.shape).astype(np.float32)
    frame.depth[rng.random(frame.depth.shape) < 0.05] = np.nan
    frame.depth[:, 150:155] = 9.0  # beyond max_depth
    frame.depth[:, 300] = -0.0
    masks = {name: np.zeros_like(sphere) for name in ("tiny", "sliver", "no_depth", "flat", "cut", "sparse", "empty")}
    masks["tiny"][10:15, 100:105] = True
    masks["sliver"][0:6, 100:140] = True
    masks["no_depth"][180:230, 200:260] = True
    frame.depth[180:230, 200:260] = 0.0
    masks["flat"][20:80, 240:300] = True  # the wall at 4 m: flat but for the noise
    masks["cut"][150:230, 0:60] = True
    masks["sparse"] = sphere & (rng.random(sphere.shape) < 0.3)
    frame.depth[30:60, 30:60] = 2.0  # a flat square: noise alone gives it thickness
    masks["square"] = np.zeros_like(sphere)
    masks["square"][30:60, 30:60] = True
    stack = [sphere, sphere & (rng.random(sphere.shape) < 0.9), *masks.values()]
    boxes = mask_boxes(np.stack(stack))
    boxes[-1] = (5.0, 5.0, 5.0, 5.0)  # the empty mask: a point of a box
    detections = Detections(np.stack(stack), boxes, np.zeros(len(stack), int), np.ones(len(stack)),
                            np.arange(len(stack)))
    reasons = set()
    for params in (ObservationParams(min_mask_pixels=50),
                   ObservationParams(fit=FitParams(max_points=700, min_axis=0.002)),
                   ObservationParams(erode_px=0, border_px=0, min_mask_pixels=1)):
        for in_boxes in (False, True):
            detections.masks_in_boxes = in_boxes
            assert _plain(frame, detections)
            passed, wanted = _frame_pass(frame, detections, params), each_detection(frame, detections, params)
            got = extract_observations(frame, detections, params)
            fits = iter(zip(got.observations.ellipsoids.centers, got.observations.ellipsoids.axes,
                            got.observations.ellipsoids.rotations))
            for k, (reason, fit, pixels, in_band) in enumerate(wanted):
                assert ((passed.pixels[k], passed.in_band[k]) == (pixels, in_band)
                        and passed.outcomes[k] != _Outcome.LEFT)
                reasons.add(reason)
                if fit is not None:
                    for a, b in zip(next(fits), fit):
                        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
            assert (got.observations.detection_index.tolist()
                    == [k for k, want in enumerate(wanted) if want[1] is not None])
            kept = [want for want in wanted if want[1] is not None]  # their areas and border flags, as plain ints
            assert got.observations.mask_areas.tolist() == [want[2] for want in kept]
            assert [c.truncated for c in got.crops] == [want[3] > 0 for want in kept]
            assert got.dropped == {r: sum(want[0] == r for want in wanted) for r in got.dropped}
    assert reasons == {None, "tiny mask", "border sliver", "invalid depth", "degenerate fit"}
    frame.intrinsics = frame.intrinsics.astype(np.float32)
    assert not _plain(frame, detections)
    assert len(extract_observations(frame, detections).observations) > 0


def test_a_scatter_numba_refuses_is_left_to_numpy():
    """Intrinsics that send back-projected points to infinity: the frame pass leaves the detection to the
    detection-by-detection fit (numpy's eigh decides, as it always did)."""
    from clipclique.perception.observations import _frame_pass, _Outcome

    frame, sphere = sphere_frame()
    frame.intrinsics = frame.intrinsics.copy()
    frame.intrinsics[0, 0] = 1e-200  # x = (u - cx) z / fx near 1e202: its squares overflow
    detections = detections_of([sphere], [1])
    params = ObservationParams()
    assert _frame_pass(frame, detections, params).outcomes.tolist() == [_Outcome.LEFT]
    ((reason, fit, pixels, _),) = each_detection(frame, detections, params)
    got = extract_observations(frame, detections, params).observations
    assert reason is None and got.mask_areas.tolist() == [pixels]
    ellipsoids = got.ellipsoids
    for a, b in zip((ellipsoids.centers, ellipsoids.axes, ellipsoids.rotations), fit):
        np.testing.assert_allclose(a[0], b, rtol=1e-12, atol=1e-12)
    assert fit[1][0] > 1e200  # numpy's eigh took the infinite scatter


def test_compiled_closures_capture_integers_alone():
    """numba's cache keys a closure by its captured values, pickled: a captured dispatcher pickles with a per-process
    id, so the frame pass would compile again in every process (seconds); integers key it the same each time."""
    from clipclique.perception.observations import _compiled_frame_pass

    for compiled in (_compiled_frame_pass(20, 2), _depth_points(20, 2)):
        captured = [cell.cell_contents for cell in compiled.py_func.__closure__]
        assert captured and all(type(value) is int for value in captured)
