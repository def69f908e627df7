"""Plain data carried between stages: struct-of-arrays so every stage stays vectorized.

Conventions used everywhere:
- A pose is camera-to-map (or camera-to-world) as a rigid transform, `x_map = R @ x_cam + t`.
- Ellipsoid axes are semi-axis lengths in metres; `rotations[i]` has the axis directions as
  its columns, so a point on ellipsoid i is `center + R @ (axes * unit_sphere_point)`.
- Class ids index into the map's class vocabulary (`Map.class_names`).
- Instance ids are the dataset's object ids; -1 means unknown. They are never used by the
  algorithm, only to score it against ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MAX_DEPTH_M = 8.0  # metres: the default range of an RGB-D camera (config.observations.max_depth)


@dataclass(frozen=True)
class Pose:
    """A rigid transform in SE(3): `apply(x) = rotation @ x + translation`."""

    rotation: np.ndarray  # (3, 3), orthonormal, det +1
    translation: np.ndarray  # (3,)

    @staticmethod
    def identity() -> Pose:
        return Pose(np.eye(3), np.zeros(3))

    @staticmethod
    def from_matrix(matrix: np.ndarray) -> Pose:
        matrix = np.asarray(matrix, dtype=np.float64)
        return Pose(matrix[:3, :3].copy(), matrix[:3, 3].copy())

    def matrix(self) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3] = self.rotation
        out[:3, 3] = self.translation
        return out

    def inverse(self) -> Pose:
        rt = self.rotation.T
        return Pose(rt, -rt @ self.translation)

    def compose(self, other: Pose) -> Pose:
        """self ∘ other: apply `other` first, then `self`."""
        return Pose(self.rotation @ other.rotation, self.rotation @ other.translation + self.translation)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform (N, 3) or (3,) points."""
        return np.asarray(points) @ self.rotation.T + self.translation


@dataclass
class Ellipsoids:
    """N ellipsoids, one row each."""

    centers: np.ndarray  # (N, 3)
    axes: np.ndarray  # (N, 3) semi-axis lengths, metres
    rotations: np.ndarray  # (N, 3, 3), columns = axis directions

    @staticmethod
    def empty() -> Ellipsoids:
        return Ellipsoids(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3)))

    def __len__(self) -> int:
        return len(self.centers)

    def subset(self, index: np.ndarray) -> Ellipsoids:
        return Ellipsoids(self.centers[index], self.axes[index], self.rotations[index])

    def transformed(self, pose: Pose) -> Ellipsoids:
        """The same ellipsoids expressed in the frame `pose` maps into."""
        return Ellipsoids(
            pose.apply(self.centers), self.axes.copy(), np.einsum("ij,njk->nik", pose.rotation, self.rotations)
        )


@dataclass
class Map:
    """A prior map: labelled ellipsoid landmarks in the dataset's world frame."""

    ellipsoids: Ellipsoids
    class_ids: np.ndarray  # (N,) int, index into class_names
    class_names: list[str]  # the class vocabulary
    descriptions: list[str]  # (N,) free text, e.g. "a purple office chair"
    instance_ids: np.ndarray  # (N,) int, dataset object id
    text_embeddings: np.ndarray | None = None  # (N, D) float32, L2-normalized
    encoder: str = "none"  # name of what made text_embeddings, or "none"
    provenance: dict = field(default_factory=dict)
    # (N, C) float, rows summing to 1: each landmark's class distribution over class_names, where
    # the map's source says how sure it is (an imported SLAM map's class counts); None: the classes
    # are certain (one-hot class_ids). Used only when `similarity.soft_classes` is on.
    class_distributions: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.class_ids)

    def subset(self, index: np.ndarray) -> Map:
        """The landmarks at `index`, in that order, with the same vocabulary."""
        return Map(self.ellipsoids.subset(index), self.class_ids[index], list(self.class_names),
                   [self.descriptions[i] for i in np.asarray(index).ravel()], self.instance_ids[index],
                   None if self.text_embeddings is None else self.text_embeddings[index], self.encoder,
                   dict(self.provenance))

    def transformed(self, pose: Pose) -> Map:
        """The same map expressed in the frame `pose` maps into."""
        return Map(self.ellipsoids.transformed(pose), self.class_ids, list(self.class_names), list(self.descriptions),
                   self.instance_ids, self.text_embeddings, self.encoder, dict(self.provenance))


@dataclass
class Frame:
    """One RGB-D query frame as a dataset reader yields it."""

    index: int  # position in the sequence
    timestamp: float  # seconds (TUM) or the frame number (ScanNet)
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres, 0 = invalid
    intrinsics: np.ndarray  # (3, 3)
    pose: Pose | None  # ground truth camera-to-world, None when unknown
    instances: np.ndarray | None = None  # (H, W) int32 dataset object id per pixel, 0 = none
    name: str = ""  # file stem, for messages


@dataclass
class Detections:
    """2D detections of one frame, from any detector back-end."""

    masks: np.ndarray  # (K, H, W) bool
    boxes: np.ndarray  # (K, 4) float xyxy pixels
    class_ids: np.ndarray  # (K,) int, in the map's vocabulary
    scores: np.ndarray  # (K,) float
    instance_ids: np.ndarray  # (K,) int, ground-truth object id, -1 unknown (false positive)
    masks_in_boxes: bool = False  # every mask lies inside its box: a reader may read the box alone

    def __len__(self) -> int:
        return len(self.class_ids)


@dataclass(frozen=True)
class Camera:
    """The pinhole camera a query was taken with: what projecting the map into its image needs."""

    intrinsics: np.ndarray  # (3, 3)
    width: int  # pixels
    height: int
    max_depth: float = MAX_DEPTH_M  # metres: objects farther than this are not observed


@dataclass
class Observations:
    """Objects seen in one frame, as ellipsoids in the camera frame."""

    ellipsoids: Ellipsoids  # camera frame
    class_ids: np.ndarray  # (K,) int, map vocabulary
    image_embeddings: np.ndarray | None  # (K, D) float32, L2-normalized
    instance_ids: np.ndarray  # (K,) int, ground-truth object id, -1 unknown
    detection_index: np.ndarray  # (K,) int, row in the Detections this came from
    boxes: np.ndarray | None = None  # (K, 4) float xyxy pixels: the detection box (image verification needs it)
    mask_areas: np.ndarray | None = None  # (K,) int, pixels of the detection mask
    camera: Camera | None = None  # None: the query cannot be verified in the image
    # (K,) bool: the observation has a box in the query image (a fused window's objects the newest frame does
    # not see have none; verification and confidence leave those out). None: every observation has one.
    has_box: np.ndarray | None = None
    scores: np.ndarray | None = None  # (K,) float, the detector's score of each detection; None: unknown

    def __len__(self) -> int:
        return len(self.class_ids)

    def subset(self, index: np.ndarray) -> Observations:
        """The observations at `index`, in that order (camera kept)."""
        pick = lambda array: None if array is None else array[index]  # noqa: E731
        return Observations(self.ellipsoids.subset(index), self.class_ids[index], pick(self.image_embeddings),
                            self.instance_ids[index], self.detection_index[index], pick(self.boxes),
                            pick(self.mask_areas), self.camera, pick(self.has_box), pick(self.scores))


@dataclass
class Hypothesis:
    """One pose candidate and the correspondences that support it."""

    pose: Pose  # camera-to-map
    correspondences: np.ndarray  # (M, 2) int, columns (observation index, landmark index)
    score: float  # the ranking score (summed similarity for cliques, inlier score for RANSAC)
    # sigma_2 / sigma_1 of the correspondences' centres (pose.conditioning, the smaller of the
    # observed and the map side): near 0, a row of objects whose rotation is ill-determined.
    # NaN when not measured (only the pipeline measures it).
    conditioning: float = float("nan")
    verification: float | None = None  # image verification score (clipclique.verify.verification); None: not verified
    confidence: float | None = None  # P(pose within the success threshold), clipclique.verify.confidence; None: unknown
