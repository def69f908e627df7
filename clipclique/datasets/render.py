"""CPU ray casting of a labelled triangle mesh (open3d): depth, object ids, shaded RGB.

Used by the demo generator to make RGB-D frames with exact ground truth, and usable on any
labelled mesh (e.g. to project a ScanNet mesh's objects into a frame with a depth test).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clipclique.types import Pose

SUN = np.array([0.3, 0.45, 0.84]) / np.linalg.norm([0.3, 0.45, 0.84])


@dataclass
class Render:
    depth: np.ndarray  # (H, W) float32 metres along the optical axis, 0 = no hit
    faces: np.ndarray  # (H, W) int64 face hit, -1 = none
    normals: np.ndarray  # (H, W, 3) float32 world normals of the faces hit
    view: np.ndarray  # (H, W, 3) float32 unit ray directions (world)


class MeshRaycaster:
    """A triangle mesh loaded once into open3d's ray casting scene, rendered from any pinhole camera."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import open3d as o3d

        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(np.asarray(vertices, np.float32))
        mesh.triangle.indices = o3d.core.Tensor(np.asarray(faces, np.int32))
        self.scene.add_triangles(mesh)

    def render(self, intrinsics: np.ndarray, pose: Pose, shape: tuple[int, int]) -> Render:
        """Cast one ray per pixel centre (u, v) of an (H, W) image; depth is z in the camera frame."""
        h, w = shape
        fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        directions = np.stack(((u - cx) / fx, (v - cy) / fy, np.ones_like(u)), axis=-1) @ pose.rotation.T.astype(np.float32)
        rays = np.concatenate((np.broadcast_to(pose.translation.astype(np.float32), directions.shape), directions), axis=-1)
        hits = self.scene.cast_rays(self._o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32)))
        t_hit = hits["t_hit"].numpy()  # distance in units of the (unnormalized) direction = camera z
        hit = np.isfinite(t_hit)
        faces = np.where(hit, hits["primitive_ids"].numpy().astype(np.int64), -1)
        view = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        return Render(np.where(hit, t_hit, 0).astype(np.float32), faces, hits["primitive_normals"].numpy(), view)


def shade(render: Render, face_colors: np.ndarray, rng: np.random.Generator, noise: float = 3.0) -> np.ndarray:
    """Lambertian RGB from a sun and a head light, plus sensor noise; (H, W, 3) uint8."""
    hit = render.faces >= 0
    base = face_colors[np.where(hit, render.faces, 0)].astype(np.float32)
    n = render.normals
    light = 0.35 + 0.4 * np.abs(n @ SUN.astype(np.float32)) + 0.3 * np.abs(np.sum(n * render.view, axis=-1))
    rgb = base * light[..., None] + rng.normal(0.0, noise, base.shape)
    return np.where(hit[..., None], np.clip(rgb, 0, 255), 0).astype(np.uint8)


def sensor_depth(depth: np.ndarray, labels: np.ndarray, rng: np.random.Generator, max_range: float = 6.0) -> np.ndarray:
    """Kinect-like depth from exact depth: axial noise growing with range, holes at object edges and at random.

    Noise model: sigma(z) = 1.2 mm + 1.9 mm * (z - 0.4)^2 (Nguyen et al., 3DIMPVT 2012).
    """
    sigma = 0.0012 + 0.0019 * (depth - 0.4) ** 2
    noisy = depth + rng.normal(0.0, 1.0, depth.shape).astype(np.float32) * sigma
    edge = np.zeros(depth.shape, bool)
    edge[:, 1:] |= (labels[:, 1:] != labels[:, :-1]) & (np.abs(depth[:, 1:] - depth[:, :-1]) > 0.05)
    edge[1:, :] |= (labels[1:, :] != labels[:-1, :]) & (np.abs(depth[1:, :] - depth[:-1, :]) > 0.05)
    holes = (edge & (rng.random(depth.shape) < 0.6)) | (rng.random(depth.shape) < 0.005)
    valid = (depth > 0.3) & (depth < max_range) & ~holes
    return np.where(valid, noisy, 0).astype(np.float32)
