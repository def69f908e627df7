"""Map ellipsoids -> image ellipses and boxes under camera poses: the dual-quadric projection.

An ellipsoid with centre c, rotation R and semi-axes s is the unit sphere moved by
H = [[R diag(s), c], [0, 1]]; its dual quadric is Q* = H diag(1, 1, 1, -1) H^T. A camera
P = K [R_c^T | -R_c^T t_c] (pose (R_c, t_c) camera-to-map) sees its outline as the dual conic
C* = P Q* P^T (Hartley & Zisserman, 8.3), computed in the expanded form `project` gives. The tangent lines x = u of that
conic, (1, 0, -u) C* (1, 0, -u)^T = 0, give the box in closed form: u = (C*13 +- sqrt(C*13^2 - C*11 C*33)) / C*33, and
likewise v.

The projection is an ellipse only when the whole ellipsoid lies in front of the camera, so a
landmark any part of which is nearer than MIN_DEPTH (behind or around the camera), whose centre is
beyond the camera's depth range, or whose box falls outside the image, is left out (`visible` False).
Boxes are clipped to the image, as detection boxes are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from clipclique.types import Camera, Ellipsoids

MIN_DEPTH = 0.05  # metres: an ellipsoid reaching nearer than this is not projected


@dataclass
class Projection:
    """N ellipsoids seen by B cameras."""

    dual_conics: np.ndarray  # (B, N, 3, 3) C* = P Q* P^T
    boxes: np.ndarray  # (B, N, 4) xyxy pixels, clipped to the image; meaningful where visible
    visible: np.ndarray  # (B, N) bool
    depths: np.ndarray  # (B, N) metres, depth of each centre along the optical axis
    full_areas: np.ndarray  # (B, N) square pixels of each box before clipping (0 where not in front)


def project(ellipsoids: Ellipsoids, rotations: np.ndarray, translations: np.ndarray, camera: Camera) -> Projection:
    """Every map ellipsoid (N) under every camera-to-map pose (B): rotations (B, 3, 3), translations (B, 3).

    With P = V [I | -t], V = K R^T, the dual conic expands to C* = V M V^T - h h^T, where
    M = R_e diag(s^2) R_e^T is the ellipsoid's spread and h = V (c - t) its centre's image (times
    its depth). V M V^T is one (N, 9) x (9, 9) product per pose (vec(V M V^T) = (V kron V) vec(M)),
    so a map of thousands of landmarks costs a few big products, not thousands of small ones.
    """
    return project_spreads(ellipsoids.centers, spreads(ellipsoids), rotations, translations, camera)


def spreads(ellipsoids: Ellipsoids) -> np.ndarray:
    """(N, 9) each ellipsoid's spread M = R_e diag(s^2) R_e^T, flattened: the map's part of `project`, the same
    whatever the pose (`pipeline.index_map` keeps the map's; each row is the same whichever others are with it)."""
    shape = ellipsoids.rotations * ellipsoids.axes[:, None, :]  # R_e diag(s)
    return (shape @ shape.transpose(0, 2, 1)).reshape(-1, 9)


def project_spreads(centers: np.ndarray, spread: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                    camera: Camera) -> Projection:
    """`project` of ellipsoids given by their centres (N, 3) and `spreads` (N, 9)."""
    conics, boxes, visible, images, full_areas = _projections(centers, spread, rotations, translations,
                                                              camera.intrinsics, float(camera.width),
                                                              float(camera.height), float(camera.max_depth))
    return Projection(conics, boxes, visible, images[..., 2], full_areas)


@njit(cache=True)
def _projections(centers: np.ndarray, spread: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                 intrinsics: np.ndarray, width: float, height: float,
                 max_depth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_outline_boxes` of V = K R^T, vec(V M V^T) = spread (V kron V)^T and h = (c - t) V^T in one compiled call,
    each product a plain loop (three BLAS calls per pose cost more than the arithmetic). Returns the conics, boxes,
    visibility, h (B, N, 3) (its third coordinate the depth) and the full areas."""
    count, size = len(rotations), len(centers)
    view = _views(rotations, intrinsics)
    kron = _kron(view).reshape(count, 9, 9)
    images, terms = np.empty((count, size, 3)), np.empty((count, size, 9))
    for b in range(count):
        for n in range(size):
            _image_into(centers[n], translations[b], view[b], images[b, n])
            for r in range(9):
                terms[b, n, r] = _term(spread[n], kron[b, r])
    conics, boxes, visible, full_areas = _outline_boxes(terms, images, width, height, max_depth)
    return conics, boxes, visible, images, full_areas


@njit(cache=True, error_model="numpy")
def visible_boxes(centers: np.ndarray, spread: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                  intrinsics: np.ndarray, width: float, height: float,
                  max_depth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`project_spreads`'s boxes (B, N, 4), visibility (B, N) and full areas (B, N) under a camera (its intrinsics,
    width, height and max depth), the boxes and areas where visible (0 elsewhere): what image verification reads,
    without the conics it does not, for compiled callers (clipclique.verify.verification). Each (pose, landmark) as
    `_projections` computes it, but of V M V^T only the five entries a box reads (`conic_entries`); then every box
    in one pass (`_boxes_where_visible`). numpy's error model: a division by zero would give inf, not raise, and
    none occurs."""
    entries = conic_entries(np.ascontiguousarray(centers.T), np.ascontiguousarray(spread.T), rotations,
                            translations, intrinsics)
    return _boxes_where_visible(entries, width, height, max_depth, len(rotations), len(centers))


@njit(cache=True, error_model="numpy")
def conic_entries(centers_t: np.ndarray, spread_t: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                  intrinsics: np.ndarray) -> np.ndarray:
    """(6, B * N): of each of N landmarks (centres (3, N), spreads (9, N)) under each of B poses, pose after pose,
    the five dual conic entries a box reads (C*11, C*13, C*22, C*23, C*33) and the centre's depth. Each entry and
    h is a loop of its own over the landmarks' numbers laid out landmark after landmark, which LLVM runs four
    landmarks at a time (a loop computing all at once reads and writes too many arrays for it)."""
    count, size = len(rotations), centers_t.shape[1]
    view = _views(rotations, intrinsics)
    kron = _kron(view).reshape(count, 9, 9)
    entries = np.empty((6, count * size))
    image, product = np.empty((3, size)), np.empty((5, size))
    for b in range(count):
        for i in range(3):
            _image_row_into(centers_t, translations, view, b, i, image[i])
        for r, row in enumerate((0, 2, 4, 5, 8)):
            _term_row_into(spread_t, kron, b, row, product[r])
        _conic_entries_into(image, product, entries[:, b * size: (b + 1) * size])
    return entries


@njit(cache=True, inline="always")
def _image_row_into(centers_t: np.ndarray, translations: np.ndarray, view: np.ndarray, b: int, i: int,
                    out: np.ndarray) -> None:
    """Coordinate i of h = (c - t) V^T of every landmark (centres (3, N)) under pose b."""
    t0, t1, t2 = translations[b, 0], translations[b, 1], translations[b, 2]
    v0, v1, v2 = view[b, i, 0], view[b, i, 1], view[b, i, 2]
    for n in range(centers_t.shape[1]):
        out[n] = (centers_t[0, n] - t0) * v0 + (centers_t[1, n] - t1) * v1 + (centers_t[2, n] - t2) * v2


@njit(cache=True, inline="always")
def _term_row_into(spread_t: np.ndarray, kron: np.ndarray, b: int, row: int, out: np.ndarray) -> None:
    """Entry `row` of vec(V M V^T) of every landmark (spreads (9, N)) under pose b."""
    k0, k1, k2, k3, k4 = kron[b, row, 0], kron[b, row, 1], kron[b, row, 2], kron[b, row, 3], kron[b, row, 4]
    k5, k6, k7, k8 = kron[b, row, 5], kron[b, row, 6], kron[b, row, 7], kron[b, row, 8]
    for n in range(spread_t.shape[1]):
        total = spread_t[0, n] * k0 + spread_t[1, n] * k1 + spread_t[2, n] * k2 + spread_t[3, n] * k3
        total += spread_t[4, n] * k4 + spread_t[5, n] * k5 + spread_t[6, n] * k6 + spread_t[7, n] * k7
        out[n] = total + spread_t[8, n] * k8


@njit(cache=True, inline="always")
def _conic_entries_into(image: np.ndarray, product: np.ndarray, entries: np.ndarray) -> None:
    """The dual conic's C*11, C*13, C*22, C*23, C*33 (V M V^T - h h^T) and the depth h3 of each landmark, from h
    (3, N) and V M V^T's entries 11, 13, 22, 23, 33 (5, N)."""
    for n in range(image.shape[1]):
        h0, h1, depth = image[0, n], image[1, n], image[2, n]
        entries[0, n], entries[1, n], entries[2, n] = product[0, n] - h0 * h0, product[1, n] - h0 * depth, \
            product[2, n] - h1 * h1
        entries[3, n], entries[4, n], entries[5, n] = product[3, n] - h1 * depth, product[4, n] - depth * depth, depth


@njit(cache=True, error_model="numpy")
def _boxes_where_visible(entries: np.ndarray, width: float, height: float, max_depth: float, count: int,
                         size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`_outline_box` of each column of `entries` (C*11, C*13, C*22, C*23, C*33, depth; pose after pose of `size`
    landmarks): (count, size, 4) boxes, visibility and full areas, the boxes and areas 0 where not visible. One pass
    into flat arrays, which LLVM runs four columns at a time (numpy's error model: no branch to raise on a division
    by zero), then the boxes laid out."""
    total = entries.shape[1]
    corners, visible, full_areas = np.empty((4, total)), np.empty(total, np.bool_), np.empty(total)
    c11, c13, c22, c23, c33, depth = entries[0], entries[1], entries[2], entries[3], entries[4], entries[5]
    u0, v0, u1, v1 = corners[0], corners[1], corners[2], corners[3]
    for i in range(total):
        u0[i], v0[i], u1[i], v1[i], visible[i], full_areas[i] = _outline_box(c11[i], c13[i], c22[i], c23[i], c33[i],
                                                                             depth[i], width, height, max_depth)
    boxes = np.zeros((total, 4))
    for i in range(total):
        if visible[i]:
            boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3] = u0[i], v0[i], u1[i], v1[i]
        else:
            full_areas[i] = 0.0
    return boxes.reshape(count, size, 4), visible.reshape(count, size), full_areas.reshape(count, size)


@njit(cache=True)
def _views(rotations: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """(B, 3, 3) V = K R^T of each pose."""
    view = np.empty((len(rotations), 3, 3))
    for b in range(len(rotations)):
        for i in range(3):
            for j in range(3):
                view[b, i, j] = (intrinsics[i, 0] * rotations[b, j, 0] + intrinsics[i, 1] * rotations[b, j, 1]
                                 + intrinsics[i, 2] * rotations[b, j, 2])
    return view


@njit(cache=True)
def _image_into(center: np.ndarray, translation: np.ndarray, view: np.ndarray, image: np.ndarray) -> None:
    """image = (c - t) V^T, one pose and landmark."""
    x0, x1, x2 = center[0] - translation[0], center[1] - translation[1], center[2] - translation[2]
    for i in range(3):
        image[i] = x0 * view[i, 0] + x1 * view[i, 1] + x2 * view[i, 2]


@njit(cache=True)
def _term(spread: np.ndarray, kron_row: np.ndarray) -> float:
    """One entry of vec(V M V^T): the landmark's spread (9,) against one row of V kron V."""
    total = 0.0
    for k in range(9):
        total += spread[k] * kron_row[k]
    return total


@njit(cache=True)
def _kron(view: np.ndarray) -> np.ndarray:
    """(B, 3, 3, 3, 3) `np.einsum("bij,bmk->bimjk", view, view)`, compiled, without einsum's setup (a fifth of a
    frame's projection)."""
    count = view.shape[0]
    kron = np.empty((count, 3, 3, 3, 3))
    for b in range(count):
        for i in range(3):
            for m in range(3):
                for j in range(3):
                    for k in range(3):
                        kron[b, i, m, j, k] = view[b, i, j] * view[b, m, k]
    return kron


@njit(cache=True)
def _outline_boxes(spreads: np.ndarray, centers: np.ndarray, width: float, height: float,
                   max_depth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per (pose, ellipsoid), from vec(V M V^T) (B, N, 9) and h (B, N, 3): the dual conic V M V^T - h h^T, the
    box of the outline clipped to the image, whether it is visible, and the unclipped box's area (0 unless the
    ellipsoid is wholly in front). C*33 = reach^2 - depth^2 < 0 in front orders the two roots of each axis;
    elsewhere -1 stands in. One compiled pass: a dozen (B, N) numpy passes cost more than the work."""
    count, size = centers.shape[:2]
    conics = np.empty((count, size, 3, 3))
    boxes, visible, full_areas = np.empty((count, size, 4)), np.empty((count, size), np.bool_), np.empty((count, size))
    for b in range(count):
        for n in range(size):
            conic, center = conics[b, n], centers[b, n]
            for i in range(3):
                for j in range(3):
                    conic[i, j] = spreads[b, n, 3 * i + j] - center[i] * center[j]
            (boxes[b, n, 0], boxes[b, n, 1], boxes[b, n, 2], boxes[b, n, 3], visible[b, n],
             full_areas[b, n]) = _outline_box(conic[0, 0], conic[0, 2], conic[1, 1], conic[1, 2], conic[2, 2],
                                              center[2],
                                              width, height, max_depth)
    return conics, boxes, visible, full_areas


@njit(cache=True, inline="always")
def _outline_box(c11: float, c13: float, c22: float, c23: float, c33: float, depth: float, width: float, height: float,
                 max_depth: float) -> tuple[float, float, float, float, bool, float]:
    """One (pose, ellipsoid) of `_outline_boxes` from the conic entries a box reads (C*11, C*13, C*22, C*23, C*33)
    and the depth: its box (u0, v0, u1, v1), whether it is visible, and the unclipped box's area. Inlined, and without
    a branch (`&`, not `and`): `_boxes_where_visible`'s loop runs four at a time."""
    in_front = _in_front(c33, depth)
    c33 = c33 if in_front else -1.0
    root = np.sqrt(at_least_zero(c13 * c13 - c11 * c33))
    u0, u1 = (c13 + root) / c33, (c13 - root) / c33
    root = np.sqrt(at_least_zero(c23 * c23 - c22 * c33))
    v0, v1 = (c23 + root) / c33, (c23 - root) / c33
    full_area = (at_least_zero(u1 - u0) * at_least_zero(v1 - v0)) if in_front else 0.0
    u0, u1 = _clip(u0, width), _clip(u1, width)
    v0, v1 = _clip(v0, height), _clip(v1, height)
    return u0, v0, u1, v1, in_front & (depth <= max_depth) & (u1 > u0) & (v1 > v0), full_area


@njit(cache=True, inline="always")
def _in_front(c33: float, depth: float) -> bool:
    """Whether the whole ellipsoid lies more than MIN_DEPTH in front of the camera: its centre's depth less its
    half-extent along the optical axis, sqrt(C*33 + depth^2)."""
    return depth - np.sqrt(at_least_zero(c33 + depth * depth)) > MIN_DEPTH


@njit(cache=True)
def _clip(value: float, limit: float) -> float:
    """np.clip(value, 0, limit): -0 and NaN kept."""
    return 0.0 if value < 0.0 else limit if value > limit else value


@njit(cache=True)
def at_least_zero(value: float) -> float:
    """np.maximum(value, 0.0): NaN kept, +0 for -0."""
    return value if value > 0.0 or np.isnan(value) else 0.0


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of xyxy boxes, broadcast over leading dimensions (0 where both are empty)."""
    width = np.maximum(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0.0)
    height = np.maximum(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0.0)
    inter = width * height
    union = box_area(a) + box_area(b) - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def box_area(boxes: np.ndarray) -> np.ndarray:
    return np.maximum(boxes[..., 2] - boxes[..., 0], 0.0) * np.maximum(boxes[..., 3] - boxes[..., 1], 0.0)


@njit(cache=True)
def pair_iou(a: np.ndarray, b: np.ndarray) -> float:
    """`box_iou` of two boxes (4,), the same operations in the same order, for compiled loops over a
    frame's few box pairs (box_iou's dozen numpy calls cost more than the arithmetic)."""
    return corners_iou(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])


@njit(cache=True)
def corners_iou(ax0: float, ay0: float, ax1: float, ay1: float, bx0: float, by0: float, bx1: float,
                by1: float) -> float:
    """`pair_iou` of two boxes given by their corners: for a compiled loop's many pairs, which hands it numbers, not
    array views (each view or array argument costs two atomic reference-count operations)."""
    width = np.maximum(np.minimum(ax1, bx1) - np.maximum(ax0, bx0), 0.0)
    height = np.maximum(np.minimum(ay1, by1) - np.maximum(ay0, by0), 0.0)
    inter = width * height
    union = (np.maximum(ax1 - ax0, 0.0) * np.maximum(ay1 - ay0, 0.0)
             + np.maximum(bx1 - bx0, 0.0) * np.maximum(by1 - by0, 0.0) - inter)
    return inter / union if union > 0 else 0.0


def ellipse_outlines(dual_conics: np.ndarray, samples: int = 48) -> np.ndarray:
    """(N, samples + 1, 2) closed pixel outlines of the ellipses of dual conics (N, 3, 3) with C*33 < 0.

    Normalized so C*33 = -1, a dual conic reads [[A A^T - m m^T, -m], [-m^T, -1]]: centre m, shape A.
    """
    normalized = dual_conics / -dual_conics[:, 2:3, 2:3]
    centers = -normalized[:, :2, 2]
    spread = normalized[:, :2, :2] + centers[:, :, None] * centers[:, None, :]
    values, vectors = np.linalg.eigh(spread)
    shape = vectors * np.sqrt(np.maximum(values, 0.0))[:, None, :]
    angles = np.linspace(0.0, 2 * np.pi, samples + 1)
    circle = np.stack((np.cos(angles), np.sin(angles)))
    return centers[:, None, :] + np.einsum("nij,js->nsi", shape, circle)
