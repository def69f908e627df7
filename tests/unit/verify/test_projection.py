"""The dual-quadric projection of map ellipsoids into a query image."""

from __future__ import annotations

import numpy as np
import pytest
from tolerance import assert_close

from clipclique.sim.poses import look_at, random_rotation
from clipclique.types import Camera, Ellipsoids, Pose
from clipclique.verify.projection import MIN_DEPTH, box_area, box_iou, ellipse_outlines, pair_iou, project

CAMERA = Camera(np.array([[520.0, 0.0, 318.0], [0.0, 515.0, 242.0], [0.0, 0.0, 1.0]]), 640, 480, 8.0)


def sampled_box(ellipsoids: Ellipsoids, pose: Pose, samples: int = 400_000) -> np.ndarray:
    """(N, 4) bounding boxes of densely sampled surface points projected by the pinhole model."""
    rng = np.random.default_rng(0)
    unit = rng.normal(size=(samples, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    out = []
    for center, axes, rotation in zip(ellipsoids.centers, ellipsoids.axes, ellipsoids.rotations):
        points = pose.inverse().apply(center + (unit * axes) @ rotation.T) @ CAMERA.intrinsics.T
        pixels = points[:, :2] / points[:, 2:]
        out.append([*pixels.min(axis=0), *pixels.max(axis=0)])
    return np.array(out)


def test_projected_box_equals_the_sampled_surface_box_within_a_pixel():
    rng = np.random.default_rng(4)
    count = 6
    ellipsoids = Ellipsoids(rng.uniform(-0.4, 0.4, (count, 3)), rng.uniform(0.05, 0.5, (count, 3)),
                            np.array([random_rotation(rng) for _ in range(count)]))
    pose = look_at(np.array([0.3, -3.0, 0.8]), np.zeros(3))
    seen = project(ellipsoids, pose.rotation[None], pose.translation[None], CAMERA)
    expected = sampled_box(ellipsoids, pose)
    assert seen.visible.all()
    assert (expected >= 0).all() and (expected[:, 2] <= 640).all() and (expected[:, 3] <= 480).all()  # no clipping
    np.testing.assert_allclose(seen.boxes[0], expected, atol=1.0)
    outlines = ellipse_outlines(seen.dual_conics[0], samples=2000)
    np.testing.assert_allclose(np.concatenate((outlines.min(axis=1), outlines.max(axis=1)), axis=1), expected, atol=1.0)
    np.testing.assert_allclose(seen.depths[0], pose.inverse().apply(ellipsoids.centers)[:, 2])


def test_every_pose_of_a_batch_is_its_own_projection():
    rng = np.random.default_rng(5)
    ellipsoids = Ellipsoids(rng.uniform(-0.5, 0.5, (4, 3)), rng.uniform(0.1, 0.3, (4, 3)),
                            np.array([random_rotation(rng) for _ in range(4)]))
    poses = [look_at(np.array([x, -3.0, 1.0]), np.zeros(3)) for x in (-1.0, 0.0, 1.5)]
    batch = project(ellipsoids, np.array([p.rotation for p in poses]), np.array([p.translation for p in poses]), CAMERA)
    for b, pose in enumerate(poses):
        alone = project(ellipsoids, pose.rotation[None], pose.translation[None], CAMERA)
        np.testing.assert_allclose(batch.boxes[b], alone.boxes[0], atol=1e-9)


@pytest.mark.parametrize(("center", "visible"), [
    ((0.0, 0.0, 3.0), True),
    ((0.0, 0.0, -3.0), False),  # behind the camera
    ((0.0, 0.0, 0.1), False),  # around the camera: reaches behind it
    ((0.0, 0.0, 9.0), False),  # beyond the depth range
    ((30.0, 0.0, 3.0), False),  # in front, but far outside the image
])
def test_landmarks_behind_around_beyond_or_outside_are_left_out(center, visible):
    ellipsoids = Ellipsoids(np.array([center]), np.array([[0.2, 0.2, 0.2]]), np.eye(3)[None])
    seen = project(ellipsoids, np.eye(3)[None], np.zeros((1, 3)), CAMERA)
    assert bool(seen.visible[0, 0]) is visible


def test_a_landmark_at_the_border_is_clipped_to_the_image():
    ellipsoids = Ellipsoids(np.array([[1.6, 0.0, 3.0]]), np.array([[0.5, 0.3, 0.3]]), np.eye(3)[None])
    seen = project(ellipsoids, np.eye(3)[None], np.zeros((1, 3)), CAMERA)
    assert seen.visible[0, 0] and seen.boxes[0, 0, 2] == 640.0
    assert (seen.full_areas[0, 0] > (seen.boxes[0, 0, 2] - seen.boxes[0, 0, 0])
            * (seen.boxes[0, 0, 3] - seen.boxes[0, 0, 1]))


def test_box_iou():
    a = np.array([0.0, 0.0, 10.0, 10.0])
    assert box_iou(a, a) == 1.0
    assert box_iou(a, np.array([5.0, 0.0, 15.0, 10.0])) == pytest.approx(50 / 150)
    assert box_iou(a, np.array([20.0, 20.0, 30.0, 30.0])) == 0.0
    assert box_iou(np.zeros(4), np.zeros(4)) == 0.0


def test_pair_iou_is_box_iou():
    """Overlapping, nested, disjoint, touching and empty boxes."""
    rng = np.random.default_rng(0)
    corners = np.round(rng.uniform(0, 60, (400, 2, 2)), 0)  # whole pixels: shared edges and empty boxes happen
    boxes = np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)
    boxes[::17, 2] = boxes[::17, 0]  # zero width
    a, b = boxes[:200], boxes[200:]
    np.testing.assert_array_equal([pair_iou(x, y) for x, y in zip(a, b)], box_iou(a, b))
    assert box_iou(a, b).min() == 0.0 and 0.0 < box_iou(a, b).max() < 1.0


def numpy_outline_boxes(conics: np.ndarray, depths: np.ndarray, camera: Camera):
    """The boxes, visibility and full areas of `project` as written with numpy passes before they were compiled."""
    reach = np.sqrt(np.maximum(conics[..., 2, 2] + depths**2, 0.0))
    in_front = depths - reach > MIN_DEPTH
    c33 = np.where(in_front, conics[..., 2, 2], -1.0)
    boxes = np.empty(conics.shape[:2] + (4,))
    for axis_index in (0, 1):
        c_ii, c_i3 = conics[..., axis_index, axis_index], conics[..., axis_index, 2]
        root = np.sqrt(np.maximum(c_i3**2 - c_ii * c33, 0.0))
        boxes[..., axis_index], boxes[..., axis_index + 2] = (c_i3 + root) / c33, (c_i3 - root) / c33
    full_areas = np.where(in_front, box_area(boxes), 0.0)
    boxes = np.clip(boxes, 0.0, np.array([camera.width, camera.height] * 2, float))
    visible = (in_front & (depths <= camera.max_depth) & (boxes[..., 2] > boxes[..., 0]) & (boxes[..., 3]
                                                                                            > boxes[..., 1]))
    return boxes, visible, full_areas


def test_the_compiled_boxes_are_the_numpy_passes():
    """Landmarks in view, behind, around and beside the camera, cut by the image border, at the depth limit."""
    rng = np.random.default_rng(11)
    for trial in range(40):
        count = int(rng.integers(1, 60))
        centers = rng.uniform(-4.0, 4.0, (count, 3))
        if trial % 2:
            centers = np.round(centers)  # on a grid: centres exactly at the depth limit, on the axes
        ellipsoids = Ellipsoids(centers, rng.uniform(0.0, 0.6, (count, 3)),
                                np.array([random_rotation(rng) for _ in range(count)]))
        poses = [look_at(rng.uniform(-3.0, 3.0, 3), rng.uniform(-1.0, 1.0, 3)) for _ in range(int(rng.integers(1, 6)))]
        camera = Camera(CAMERA.intrinsics, 640, 480, float(rng.choice([3.0, 4.0, 8.0])))
        seen = project(ellipsoids, np.array([p.rotation for p in poses]), np.array([p.translation for p in poses]),
                       camera)
        for ours, theirs in zip((seen.boxes, seen.visible, seen.full_areas),
                                numpy_outline_boxes(seen.dual_conics, seen.depths, camera)):
            assert_close(ours, theirs)
        assert_close(seen.dual_conics, numpy_dual_conics(ellipsoids, poses, camera))


def numpy_dual_conics(ellipsoids: Ellipsoids, poses: list, camera: Camera) -> np.ndarray:
    """`project`'s dual conics as written with numpy passes, V M V^T - h h^T, before the subtraction was compiled
    (the products numpy's matmul)."""
    rotations, translations = np.array([p.rotation for p in poses]), np.array([p.translation for p in poses])
    shape = ellipsoids.rotations * ellipsoids.axes[:, None, :]
    spread = (shape @ shape.transpose(0, 2, 1)).reshape(-1, 9)
    view = camera.intrinsics @ rotations.transpose(0, 2, 1)
    kron = np.einsum("bij,blk->biljk", view, view).reshape(-1, 9, 9)
    centers = (ellipsoids.centers[None] - translations[:, None]) @ view.transpose(0, 2, 1)
    terms = spread @ kron.transpose(0, 2, 1)
    return terms.reshape(*centers.shape, 3) - centers[..., :, None] * centers[..., None, :]


def numpy_projection(ellipsoids: Ellipsoids, rotations: np.ndarray, translations: np.ndarray, camera: Camera,
                     product=np.matmul):
    """`project`'s arrays as its numpy passes computed them before the kron was compiled and the map's spreads kept."""
    from clipclique.verify.projection import _outline_boxes

    shape = ellipsoids.rotations * ellipsoids.axes[:, None, :]
    spread = (shape @ shape.transpose(0, 2, 1)).reshape(-1, 9)
    view = product(camera.intrinsics, rotations.transpose(0, 2, 1))
    kron = np.einsum("bij,blk->biljk", view, view).reshape(-1, 9, 9)
    centers = product(ellipsoids.centers[None] - translations[:, None], view.transpose(0, 2, 1))
    conics, boxes, visible, full_areas = _outline_boxes(product(spread, kron.transpose(0, 2, 1)), centers,
                                                        float(camera.width),
                                                        float(camera.height), float(camera.max_depth))
    return conics, boxes, visible, centers[..., 2], full_areas


def test_the_compiled_kron_is_einsums_outer_product():
    """`_kron` against np.einsum("bij,blk->biljk") on hand-made views (-0, NaN, infinities, subnormals, huge values
    whose products overflow) and random ones, and no views."""
    from clipclique.verify.projection import _kron

    hand = np.array([[[0.0, -0.0, 1.0], [np.nan, np.inf, -np.inf], [5e-324, 1e300, -1e-300]],
                     [[520.0, 0.0, 318.0], [0.0, 515.0, 242.0], [0.0, 0.0, 1.0]]])
    rng = np.random.default_rng(0)
    for views in (hand, rng.normal(size=(50, 3, 3)) * 300.0, np.zeros((0, 3, 3))):
        with np.errstate(invalid="ignore", over="ignore", under="ignore"):
            expected = np.einsum("bij,blk->biljk", views, views)
            got = _kron(views)
        assert got.flags.c_contiguous
        assert_close(got, expected)


def test_a_maps_spreads_are_each_ellipsoids_own_whatever_the_others():
    """The spreads `index_map` keeps for the whole map, gathered for the landmarks in range, are the values the
    landmarks in range alone give (verification projects only those), single and empty subsets included."""
    from clipclique.verify.projection import spreads

    rng = np.random.default_rng(2)
    count = 60
    ellipsoids = Ellipsoids(rng.normal(size=(count, 3)), rng.uniform(0.01, 2.0, (count, 3)),
                            np.array([random_rotation(rng) for _ in range(count)]))
    whole = spreads(ellipsoids)
    assert whole.shape == (count, 9) and whole.flags.c_contiguous
    for subset in (np.arange(count), rng.permutation(count)[:17], np.array([5]), np.zeros(0, np.int64),
                   np.sort(rng.choice(count, 31, replace=False))):
        assert_close(whole[subset], spreads(ellipsoids.subset(subset)))


def test_project_is_its_numpy_passes():
    """The projection with the compiled kron and the spreads passed separately gives the arrays the numpy passes
    gave, every pose and landmark, landmarks behind, around and beyond the camera among them."""
    from clipclique.verify.projection import project_spreads, spreads

    rng = np.random.default_rng(3)
    for trial in range(40):
        count, poses = int(rng.integers(0, 30)), int(rng.integers(1, 8))
        ellipsoids = Ellipsoids(rng.uniform(-4, 4, (count, 3)), rng.uniform(0.02, 1.5, (count, 3)),
                                np.array([random_rotation(rng) for _ in range(count)]).reshape(-1, 3, 3))
        cameras = [look_at(rng.uniform(-5, 5, 3), rng.uniform(-1, 1, 3)) for _ in range(poses)]
        rotations, translations = np.array([p.rotation for p in cameras]), np.array([p.translation for p in cameras])
        expected = numpy_projection(ellipsoids, rotations, translations, CAMERA)
        for seen in (project(ellipsoids, rotations, translations, CAMERA),
                     project_spreads(ellipsoids.centers, spreads(ellipsoids), rotations, translations, CAMERA)):
            got = (seen.dual_conics, seen.boxes, seen.visible, seen.depths, seen.full_areas)
            for ours, theirs in zip(got, expected):
                assert_close(ours, theirs)


def numpy_products(centers, spread, rotations, translations, intrinsics):
    """vec(V M V^T) and h by numpy's matmul, as `project_spreads` computed them before they were compiled."""
    view = intrinsics @ rotations.transpose(0, 2, 1)
    kron = np.einsum("bij,blk->biljk", view, view).reshape(-1, 9, 9)
    return spread @ kron.transpose(0, 2, 1), (centers[None] - translations[:, None]) @ view.transpose(0, 2, 1)


@pytest.mark.parametrize("count", [0, 2, 3, 7, 40])
def test_the_compiled_products_are_numpys_matmul(count):
    """`_projections`'s V = K R^T, h = (c - t) V^T and vec(V M V^T) against numpy's matmul, through `_outline_boxes`,
    on random poses and on hand-made entries: -0, NaN, infinities, centres on the camera (a zero offset), equal
    landmarks (ties) and no landmarks."""
    from clipclique.verify.projection import _outline_boxes, _projections

    rng = np.random.default_rng(count)
    for trial in range(30):
        poses = int(rng.integers(1, 8))
        rotations = np.array([random_rotation(rng) for _ in range(poses)])
        translations = rng.uniform(-5, 5, (poses, 3))
        centers, spread = rng.uniform(-4, 4, (count, 3)), rng.normal(size=(count, 9))
        if count and trial % 3 == 1:  # hand-made entries
            rotations[0, 0] = [-0.0, 1.0, -0.0]
            centers[0], spread[0] = translations[0], -0.0  # on the camera: offsets of 0, products of -0
            centers[-1] = centers[0]  # a tie
            spread[-1, 4] = np.nan
            centers[count // 2, 1] = np.inf if trial % 2 else -np.inf
        intrinsics = CAMERA.intrinsics
        with np.errstate(invalid="ignore", over="ignore"):
            terms, images = numpy_products(centers, spread, rotations, translations, intrinsics)
            expected = (*_outline_boxes(terms, images, 640.0, 480.0, 8.0), images)
            got = _projections(centers, spread, rotations, translations, intrinsics, 640.0, 480.0, 8.0)
        # The conics and h within rounding; the boxes (pixels) and areas (square pixels) of these random spreads, not
        # positive definite, come from square roots of differences that cancel to 1e-8 of their terms.
        # A visibility may differ only for a box thinner than that rounding (a sliver at the decision's edge).
        boxes = got[1]
        flipped = got[2] != expected[2]
        thin = np.minimum(boxes[..., 2] - boxes[..., 0], boxes[..., 3] - boxes[..., 1]) < 1e-4
        assert not (flipped & ~thin).any() and flipped.sum() <= 1
        for ours, theirs, atol in zip((got[0], got[1], got[4], got[3]), (*expected[:2], *expected[3:]),
                                      (None, 1e-4, 1e-2, None)):
            assert_close(ours, theirs, atol)


@pytest.mark.parametrize("count", [0, 1, 2, 7, 40])
def test_visible_boxes_are_the_projections_where_visible(count):
    """`visible_boxes` (the five conic entries a box reads, and only for landmarks in front within range) against
    `project_spreads`: the same visibility everywhere, the same boxes and full areas where visible and 0 elsewhere,
    on random poses facing every way and hand-made entries: -0, NaN, infinities, a landmark on the camera, equal
    landmarks (ties), beyond the depth range, one landmark and none."""
    from clipclique.verify.projection import project_spreads, spreads, visible_boxes

    rng = np.random.default_rng(11 + count)
    visible_seen = hidden_seen = 0
    for trial in range(30):
        ellipsoids = Ellipsoids(rng.uniform(-4, 4, (count, 3)), rng.uniform(0.02, 1.5, (count, 3)),
                                np.array([random_rotation(rng) for _ in range(count)]).reshape(-1, 3, 3))
        cameras = [look_at(rng.uniform(-5, 5, 3), rng.uniform(-1, 1, 3)) for _ in range(int(rng.integers(1, 8)))]
        rotations, translations = np.array([p.rotation for p in cameras]), np.array([p.translation for p in cameras])
        centers, spread = ellipsoids.centers, spreads(ellipsoids)
        if count > 1 and trial % 3 == 1:  # hand-made entries
            rotations[0, 0] = [-0.0, 1.0, -0.0]
            centers[0], spread[0] = translations[0], -0.0  # on the camera
            centers[-1], spread[-1] = centers[1], spread[1]  # a tie
            spread[count // 2, 4] = np.nan
            centers[count // 2 - 1, 1] = np.inf if trial % 2 else -np.inf
            centers[1] = translations[-1] + 30.0 * rotations[-1][:, 2]  # straight ahead, beyond the depth range
        with np.errstate(invalid="ignore", over="ignore"):
            seen = project_spreads(centers, spread, rotations, translations, CAMERA)
            boxes, visible, full_areas = visible_boxes(centers, spread, rotations, translations, CAMERA.intrinsics,
                                                       float(CAMERA.width), float(CAMERA.height),
                                                       float(CAMERA.max_depth))
        assert_close(visible, seen.visible)
        assert_close(boxes, np.where(seen.visible[..., None], seen.boxes, 0.0))
        assert_close(full_areas, np.where(seen.visible, seen.full_areas, 0.0))
        visible_seen += int(visible.sum())
        hidden_seen += int((~visible).sum())
    assert count == 0 or (visible_seen > 0 and hidden_seen > 0)


def test_the_boxes_of_flat_conic_entries_are_the_numpy_passes():
    """`_boxes_where_visible` (every box in one branch-free pass) against the numpy passes of the boxes, zeroed where
    not visible: entries in front, behind, grazing the camera (C*33 + depth^2 = 0), at the depth limit, -0, NaN and
    infinities, no landmark."""
    from clipclique.verify.projection import _boxes_where_visible

    camera = Camera(CAMERA.intrinsics, 640, 480, 4.0)
    rng = np.random.default_rng(23)
    visible_seen = hidden_seen = 0
    for trial in range(60):
        count, size = int(rng.integers(1, 5)), int(rng.integers(0, 30))
        depth = rng.choice([-1.0, 0.0, 0.05, 1.0, 2.5, 4.0, 6.0], size=(count, size))
        conics = np.zeros((count, size, 3, 3))
        conics[..., 2, 2] = -depth**2 + rng.choice([0.0, 0.01, 0.3, 2.0], size=(count, size))
        for i, j in ((0, 0), (0, 2), (1, 1), (1, 2)):
            conics[..., i, j] = rng.normal(scale=300.0, size=(count, size)) * depth + rng.normal(size=(count, size))
        if trial % 3 == 0 and size:
            conics[0, 0, 0, 2], conics[-1, -1, 2, 2] = rng.choice([np.nan, np.inf, -0.0]), rng.choice([np.nan, -np.inf])
            depth[0, -1] = rng.choice([np.nan, np.inf, -0.0])
        entries = np.stack([conics[..., 0, 0], conics[..., 0, 2], conics[..., 1, 1], conics[..., 1, 2],
                            conics[..., 2, 2],
                            depth]).reshape(6, -1)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            boxes, visible, full_areas = numpy_outline_boxes(conics, depth, camera)
            got = _boxes_where_visible(entries, 640.0, 480.0, 4.0, count, size)
        expected = (np.where(visible[..., None], boxes, 0.0), visible, np.where(visible, full_areas, 0.0))
        for ours, theirs in zip(got, expected, strict=True):
            assert ours.dtype == theirs.dtype
            assert_close(ours, theirs)
        visible_seen, hidden_seen = visible_seen + int(visible.sum()), hidden_seen + int((~visible).sum())
    assert visible_seen > 100 and hidden_seen > 100


def test_corners_iou_is_box_iou():
    """`corners_iou` (the numbers of two boxes, as verification's loops hand them) against `box_iou`:
    overlapping, nested, disjoint, touching and empty boxes, corners of -0, NaN and infinity."""
    from clipclique.verify.projection import corners_iou

    rng = np.random.default_rng(2)
    corners = np.round(rng.uniform(-5, 60, (600, 2, 2)), 0)
    boxes = np.concatenate((corners.min(axis=1), corners.max(axis=1)), axis=1)
    boxes[::17, 2] = boxes[::17, 0]  # zero width
    special = rng.random(boxes.shape) < 0.05
    boxes[special] = rng.choice([-0.0, np.nan, np.inf, -np.inf], int(special.sum()))
    a, b = boxes[:300], boxes[300:]
    with np.errstate(invalid="ignore"):
        expected = box_iou(a, b)
    got = np.array([corners_iou(*x, *y) for x, y in zip(a, b)])
    assert_close(got, expected)
    assert np.isnan(boxes).any() and (expected > 0).any() and (expected == 0).any()
