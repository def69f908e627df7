"""CPU ray casting of a triangle mesh (open3d): depth, faces hit, normals.

Used by the ScanNet reader to project the labelled mesh's objects into a frame (with a depth
test) and by the scene generator (clipclique.sim) to render frames with exact ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clipclique.types import Pose


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
        directions = (np.stack(((u - cx) / fx,
                                (v - cy) / fy, np.ones_like(u)), axis=-1) @ pose.rotation.T.astype(np.float32))
        rays = np.concatenate((np.broadcast_to(pose.translation.astype(np.float32), directions.shape), directions),
                              axis=-1)
        hits = self.scene.cast_rays(self._o3d.core.Tensor(np.ascontiguousarray(rays, dtype=np.float32)))
        t_hit = hits["t_hit"].numpy()  # distance in units of the (unnormalized) direction = camera z
        hit = np.isfinite(t_hit)
        faces = np.where(hit, hits["primitive_ids"].numpy().astype(np.int64), -1)
        view = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        return Render(np.where(hit, t_hit, 0).astype(np.float32), faces, hits["primitive_normals"].numpy(), view)
