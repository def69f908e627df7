"""A SLAM map into a dataset's ground-truth frame: its keyframe trajectory fitted to the ground
truth by timestamps (Umeyama through `clipclique.pose.fit.fit_similarity`: rigid for RGB-D maps,
with scale for monocular ones), refused when the fit is poor, and recorded in the map's provenance.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clipclique.datasets.tum import associate, read_trajectory
from clipclique.interop.errors import InteropError
from clipclique.pose.fit import DegeneratePoseError, Similarity, fit_similarity
from clipclique.types import Ellipsoids, Map


@dataclass(frozen=True)
class AlignmentLimits:
    """When a fit is refused: a published fr2/desk map fits its ground truth to about 1 cm over ~200 keyframes."""

    min_matched: int = 10  # keyframes matched to a ground-truth pose
    max_rmse_m: float = 0.05  # RMSE of the matched keyframe positions after the fit
    max_time_diff_s: float = 0.02  # a keyframe matches the nearest ground-truth pose within this


@dataclass(frozen=True)
class Alignment:
    """The transform from the SLAM frame to the ground-truth frame and how well it fits."""

    transform: Similarity  # x_gt = scale * R x_slam + t
    rmse_m: float
    matched: int
    with_scale: bool

    def record(self, trajectory: Path, groundtruth: Path) -> dict:
        """What the map's provenance keeps of the alignment."""
        return {"matrix": self.transform.matrix().tolist(), "scale": self.transform.scale, "rmse_m": self.rmse_m,
                "matched_keyframes": self.matched, "with_scale": self.with_scale,
                "trajectory": str(trajectory), "groundtruth": str(groundtruth)}


def align_trajectory(trajectory: Path, groundtruth: Path, with_scale: bool = False,
                     limits: AlignmentLimits = AlignmentLimits()) -> Alignment:
    """The fit of a TUM keyframe trajectory (SLAM frame) to a TUM ground truth; InteropError, one line,
    when too few keyframes match or the RMSE is above the limit."""
    times, poses = read_trajectory(Path(trajectory))
    truth_times, truth = read_trajectory(Path(groundtruth))
    nearest = associate(times, truth_times, limits.max_time_diff_s)
    matched = np.flatnonzero(nearest >= 0)
    if len(matched) < limits.min_matched:
        raise InteropError(f"{trajectory}: {len(matched)} of {len(times)} keyframes match a pose of {groundtruth} "
                           f"within {limits.max_time_diff_s:g} s; an alignment needs {limits.min_matched} "
                           "(is it the same sequence?)")
    source = np.array([poses[i].translation for i in matched])
    target = np.array([truth[nearest[i]].translation for i in matched])
    try:
        transform = fit_similarity(source, target, with_scale)
    except DegeneratePoseError as error:
        raise InteropError(f"{trajectory}: the keyframes cannot fix an alignment ({error})") from None
    rmse = float(np.sqrt(np.mean(np.sum((transform.apply(source) - target) ** 2, axis=1))))
    if rmse > limits.max_rmse_m:
        hint = "" if with_scale else "; a monocular map needs --scale"
        raise InteropError(f"{trajectory}: the keyframes fit {groundtruth} with {rmse * 100:.1f} cm RMSE over "
                           f"{len(matched)} keyframes, above the {limits.max_rmse_m * 100:g} cm allowed{hint}")
    return Alignment(transform, rmse, len(matched), with_scale)


def aligned_map(map: Map, alignment: Alignment, sequence: str, record: dict) -> Map:
    """`map` moved into the ground-truth frame of `sequence` (axes scaled by the fit's scale), its
    provenance naming that sequence (so `clipclique-loc run` takes it as its map) and the alignment."""
    transform = alignment.transform
    rotation = transform.pose.rotation
    ellipsoids = Ellipsoids(transform.apply(map.ellipsoids.centers), map.ellipsoids.axes * transform.scale,
                            np.einsum("ij,njk->nik", rotation, map.ellipsoids.rotations))
    provenance = dict(map.provenance)
    provenance["source"] = dict(provenance.get("source", {})) | {"name": sequence}
    provenance["alignment"] = record
    return Map(ellipsoids, map.class_ids, map.class_names, map.descriptions, map.instance_ids, map.text_embeddings,
               map.encoder, provenance, map.class_distributions)
