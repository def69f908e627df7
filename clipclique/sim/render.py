"""What a camera makes of a ray-cast render (clipclique.perception.raycast): shaded RGB and Kinect-like depth."""

from __future__ import annotations

import numpy as np

from clipclique.perception.raycast import Render

SUN = np.array([0.3, 0.45, 0.84]) / np.linalg.norm([0.3, 0.45, 0.84])


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
