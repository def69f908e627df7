"""Map ellipsoids -> image ellipses and boxes under camera poses: the dual-quadric projection.

An ellipsoid with centre c, rotation R and semi-axes s is the unit sphere moved by
H = [[R diag(s), c], [0, 1]]; its dual quadric is Q* = H diag(1, 1, 1, -1) H^T. A camera
P = K [R_c^T | -R_c^T t_c] (pose (R_c, t_c) camera-to-map) sees its outline as the dual conic
C* = P Q* P^T (Hartley & Zisserman, 8.3). The tangent lines x = u of that conic, (1, 0, -u) C* (1, 0, -u)^T = 0,
give the box in closed form: u = (C*13 +- sqrt(C*13^2 - C*11 C*33)) / C*33, and likewise v.

The projection is an ellipse only when the whole ellipsoid lies in front of the camera, so a
landmark any part of which is nearer than MIN_DEPTH (behind or around the camera), whose centre is
beyond the camera's depth range, or whose box falls outside the image, is left out (`visible` False).
Boxes are clipped to the image, as detection boxes are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def dual_quadrics(ellipsoids: Ellipsoids) -> np.ndarray:
    """(N, 4, 4) Q* of each ellipsoid."""
    shape = ellipsoids.rotations * ellipsoids.axes[:, None, :]  # R diag(s)
    centers = ellipsoids.centers
    out = np.empty((len(ellipsoids), 4, 4))
    out[:, :3, :3] = shape @ shape.transpose(0, 2, 1) - centers[:, :, None] * centers[:, None, :]
    out[:, :3, 3] = out[:, 3, :3] = -centers
    out[:, 3, 3] = -1.0
    return out


def camera_matrices(rotations: np.ndarray, translations: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """(B, 3, 4) P = K [R^T | -R^T t] of camera-to-map poses (B, 3, 3), (B, 3)."""
    world_to_camera = np.concatenate(
        (rotations.transpose(0, 2, 1), -np.einsum("bji,bj->bi", rotations, translations)[:, :, None]), axis=2)
    return intrinsics @ world_to_camera


def project(ellipsoids: Ellipsoids, rotations: np.ndarray, translations: np.ndarray, camera: Camera) -> Projection:
    """Every map ellipsoid (N) under every camera-to-map pose (B): rotations (B, 3, 3), translations (B, 3)."""
    matrices = camera_matrices(rotations, translations, camera.intrinsics)
    conics = np.einsum("bij,njk,blk->bnil", matrices, dual_quadrics(ellipsoids), matrices)
    # Depth of the centre, and the ellipsoid's half-extent along the optical axis (K's last row is (0, 0, 1)).
    axis = rotations[:, :, 2]  # (B, 3) the optical axis in the map frame
    depths = np.einsum("bi,ni->bn", axis, ellipsoids.centers) - np.einsum("bi,bi->b", axis, translations)[:, None]
    reach = np.linalg.norm(np.einsum("bi,nij->bnj", axis, ellipsoids.rotations) * ellipsoids.axes[None], axis=2)
    in_front = depths - reach > MIN_DEPTH
    c33 = np.where(in_front, conics[..., 2, 2], -1.0)  # in front: C*33 = reach^2 - depth^2 < 0
    boxes = np.empty(conics.shape[:2] + (4,))
    for axis_index in (0, 1):  # u from (C*11, C*13), v from (C*22, C*23)
        c_ii, c_i3 = conics[..., axis_index, axis_index], conics[..., axis_index, 2]
        root = np.sqrt(np.maximum(c_i3**2 - c_ii * c33, 0.0))
        ends = np.sort(np.stack(((c_i3 + root) / c33, (c_i3 - root) / c33)), axis=0)
        boxes[..., axis_index], boxes[..., axis_index + 2] = ends[0], ends[1]
    full_areas = np.where(in_front, box_area(boxes), 0.0)
    boxes = np.clip(boxes, 0.0, np.array([camera.width, camera.height] * 2, float))
    visible = (in_front & (depths <= camera.max_depth)
               & (boxes[..., 2] > boxes[..., 0]) & (boxes[..., 3] > boxes[..., 1]))
    return Projection(conics, boxes, visible, depths, full_areas)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of xyxy boxes, broadcast over leading dimensions (0 where both are empty)."""
    width = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0.0, None)
    height = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0.0, None)
    inter = width * height
    union = box_area(a) + box_area(b) - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def box_area(boxes: np.ndarray) -> np.ndarray:
    return np.clip(boxes[..., 2] - boxes[..., 0], 0.0, None) * np.clip(boxes[..., 3] - boxes[..., 1], 0.0, None)


def ellipse_outlines(dual_conics: np.ndarray, samples: int = 48) -> np.ndarray:
    """(N, samples + 1, 2) closed pixel outlines of the ellipses of dual conics (N, 3, 3) with C*33 < 0.

    Normalized so C*33 = -1, a dual conic reads [[A A^T - m m^T, -m], [-m^T, -1]]: centre m, shape A.
    """
    normalized = dual_conics / -dual_conics[:, 2:3, 2:3]
    centers = -normalized[:, :2, 2]
    spread = normalized[:, :2, :2] + centers[:, :, None] * centers[:, None, :]
    values, vectors = np.linalg.eigh(spread)
    shape = vectors * np.sqrt(np.clip(values, 0.0, None))[:, None, :]
    angles = np.linspace(0.0, 2 * np.pi, samples + 1)
    circle = np.stack((np.cos(angles), np.sin(angles)))
    return centers[:, None, :] + np.einsum("nij,js->nsi", shape, circle)
