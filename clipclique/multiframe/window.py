"""Several frames as one query: observations of a short window moved into the newest frame and fused.

A frame that sees two mapped objects cannot be localized alone, but beside its neighbours it can:
the observations of the last K frames (every S-th frame back from the newest) are moved into the
newest camera frame by relative odometry (`poses[i]` maps frame i's camera coordinates into the
newest frame's) and fused per object, then localized by the unchanged pipeline.

Fusion, frame by frame from the newest back: an observation joins a fused object when
- its class is the object's or a look-alike of it (`lookalikes.LOOKALIKE_PAIRS`, by class name),
- the ellipsoids overlap: the centre distance is below `WindowConfig.overlap` times the sum of the
  two ellipsoids' radii along the line between the centres (against any member),
- and the object holds no observation of that frame yet (two detections of one frame are two objects);
otherwise it starts an object of its own. Candidates are assigned nearest first (one-to-one).

A fused object is merged by moments: each member an ellipsoid of uniform density (covariance
R diag(a^2 / 5) R^T), equal weight per member; the merged mean and covariance give the centre, the
axes (sqrt(5 * eigenvalue), largest first) and the rotation. A one-member object keeps its
ellipsoid as it is. Its class is the members' most frequent class (ties: the newest member's), so
a cup called "bottle" once and "cup" thrice is a cup; its CLIP image embedding is the members'
mean, re-normalized (several crops of one object average their noise); its Semantic Histogram is
built by the pipeline from the fused classes and centres, as for any query. The ground-truth
instance id (scoring only) is the members' most frequent.

The fused object keeps its detection box, mask area and detection index of the newest frame when
the newest frame sees it (`Observations.has_box`); the others have none (a zero box, area 0,
detection index -1), and image verification and confidence leave them out. Objects the newest
frame sees come first, in the newest frame's order, so their indices are the newest frame's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from clipclique.descriptors import lookalikes
from clipclique.types import Ellipsoids, Observations, Pose

UNIFORM_VARIANCE = 5.0  # a solid ellipsoid of semi-axis a has variance a^2 / 5 along it


@dataclass(frozen=True)
class WindowConfig:
    """Which frames form the window and when two observations are one object."""

    size: int = 1  # K frames: the newest and K - 1 before it
    step: int = 1  # S: every S-th frame back from the newest
    overlap: float = 0.5  # centre distance / summed radii along the centre line below which two observations merge


@dataclass
class Fusion:
    """Fused observations and where each came from."""

    observations: Observations  # in the newest frame's camera coordinates
    members: list[np.ndarray]  # per fused observation, (M, 2) int rows (source frame, observation index there)
    moved: list[Ellipsoids]  # per source frame, its observations moved into the newest frame
    sources: list[Observations]  # per source frame, its observations as given (its own camera's coordinates)


@dataclass
class WindowQuery:
    """The query of one newest frame: its window fused, and what went into it."""

    fusion: Fusion
    frames: list[int]  # the frames fused, oldest first, the newest last
    poses: list[Pose]  # their cameras in the newest camera's frame (odometry)
    without_odometry: int  # frames of the window left out for want of odometry

    @property
    def observations(self) -> Observations:
        return self.fusion.observations


class Windower:
    """Fused queries along a sequence; each frame's observations are made once and kept while a window needs them."""

    def __init__(self, config: WindowConfig, odometry: list[Pose | None], class_names: list[str]) -> None:
        self.config = config
        self.odometry = odometry  # camera-to-odometry-world per frame of the sequence, None where unknown
        self.class_names = class_names
        self._seen: dict[int, Observations] = {}

    def query(self, newest: int, observations: Observations,
              observe: Callable[[int], Observations]) -> WindowQuery:
        """The window ending at frame `newest` (whose `observations` are given); `observe(i)` makes an
        earlier frame's when no earlier query made them."""
        members = window_frames(newest, self.config)
        poses, kept = relative_poses([self.odometry[i] for i in members])
        frames = [i for i, keep in zip(members, kept) if keep]
        self._seen = {i: seen for i, seen in self._seen.items() if i >= members[0]}
        self._seen[newest] = observations
        for i in frames:
            if i not in self._seen:
                self._seen[i] = observe(i)
        fused = fusion([self._seen[i] for i in frames], poses, self.config, self.class_names)
        return WindowQuery(fused, frames, poses, int(np.count_nonzero(~kept)))


def span_step(span_s: float, size: int, timestamps: np.ndarray) -> int:
    """The step S that spreads K = `size` frames over about `span_s` seconds at the median interval of
    `timestamps` (at least 1): a window that reaches past a stretch of poor views whatever the frame rate."""
    intervals = np.diff(np.asarray(timestamps, float))
    interval = float(np.median(intervals)) if len(intervals) else 0.0
    if size < 2 or not interval > 0:
        return 1
    return max(1, int(round(span_s / ((size - 1) * interval))))


def window_frames(newest: int, config: WindowConfig) -> list[int]:
    """Indices of the window ending at frame `newest`, oldest first; the first frames have a shorter one."""
    first = newest - (config.size - 1) * config.step
    return list(range(newest, max(first, newest % config.step) - 1, -config.step))[::-1]


def fuse(observations: list[Observations], poses: list[Pose], config: WindowConfig = WindowConfig(),
         class_names: list[str] | None = None) -> Observations:
    """One query from the observations of several frames; the last frame is the newest (its boxes and
    camera are kept). `class_names` (the vocabulary of the class ids) lets look-alike classes merge;
    without it only equal classes do."""
    return fusion(observations, poses, config, class_names).observations


def fusion(observations: list[Observations], poses: list[Pose], config: WindowConfig = WindowConfig(),
           class_names: list[str] | None = None) -> Fusion:
    """`fuse`, with the members of every fused observation and each frame's moved observations."""
    if not observations or len(observations) != len(poses):
        raise ValueError(f"fuse needs one pose per observation set and at least one set "
                         f"({len(observations)} sets, {len(poses)} poses)")
    moved = [frame.ellipsoids.transformed(pose) for frame, pose in zip(observations, poses)]
    newest = observations[-1]
    if len(observations) == 1:
        members = [np.array([[0, k]]) for k in range(len(newest))]
        return Fusion(newest, members, moved, observations)
    same = _class_kernel(observations, class_names)
    clusters: list[list[tuple[int, int]]] = [[(len(observations) - 1, k)] for k in range(len(newest))]
    for frame in range(len(observations) - 2, -1, -1):
        _assign(frame, observations, moved, clusters, same, config.overlap)
    return Fusion(_merge(observations, moved, clusters), [np.array(c) for c in clusters], moved, observations)


def relative_poses(odometry: list[Pose | None]) -> tuple[list[Pose], np.ndarray]:
    """Poses of the window's frames (odometry camera-to-world, oldest first, the newest last) in the newest
    camera's frame, for the frames that have odometry; and which frames kept (bool). Without odometry
    for the newest frame only the newest is kept (with the identity)."""
    kept = np.array([pose is not None for pose in odometry])
    newest = odometry[-1]
    if newest is None:
        kept[:] = False
        kept[-1] = True
        return [Pose.identity()], kept
    to_newest = newest.inverse()
    poses = [to_newest.compose(pose) for pose in odometry[:-1] if pose is not None]
    return poses + [Pose.identity()], kept


def _class_kernel(observations: list[Observations], class_names: list[str] | None) -> sp.csr_matrix:
    count = max((int(frame.class_ids.max()) + 1 for frame in observations if len(frame)), default=1)
    if class_names is None:
        return sp.identity(count, format="csr")
    if count > len(class_names):
        raise ValueError(f"class id {count - 1} is outside the {len(class_names)} class names given")
    return lookalikes.class_kernel(class_names, 1.0)



def _radii(rotations: np.ndarray, axes: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(n, m) distance from each of n ellipsoids' centres to its surface along each of its m unit directions."""
    local = np.einsum("nij,nmi->nmj", rotations, directions) / axes[:, None]
    return 1.0 / np.sqrt(np.einsum("nmj,nmj->nm", local, local))


def _assign(frame: int, observations: list[Observations], moved: list[Ellipsoids],
            clusters: list[list[tuple[int, int]]],
            same: sp.csr_matrix, overlap: float) -> None:
    """Add each observation of `frame` to the nearest overlapping fused object of a like class that has none
    of this frame (nearest pairs first), or start a new object."""
    count = len(observations[frame])
    owner = np.repeat(np.arange(len(clusters)), [len(cluster) for cluster in clusters])
    sources = np.concatenate(clusters) if clusters else np.zeros((0, 2), np.int64)
    ratio = np.full((count, len(clusters)), np.inf)
    if count and len(sources):
        ours = moved[frame]
        theirs = Ellipsoids(*(np.array([getattr(moved[f], name)[k] for f, k in sources])
                              for name in ("centers", "axes", "rotations")))
        offsets = theirs.centers[None] - ours.centers[:, None]  # (n, M, 3)
        distance = np.linalg.norm(offsets, axis=2)
        directions = offsets / np.where(distance > 0, distance, 1.0)[..., None]
        directions[distance == 0] = (1.0, 0.0, 0.0)
        reach = (_radii(ours.rotations, ours.axes, directions)
                 + _radii(theirs.rotations, theirs.axes, directions.transpose(1, 0, 2)).T)
        seeds = np.array([observations[f].class_ids[k] for f, k in (cluster[0] for cluster in clusters)])
        like = same[observations[frame].class_ids][:, seeds[owner]].toarray() > 0
        np.minimum.at(ratio, (slice(None), owner), np.where(like, distance / reach, np.inf))
    rows, cols = np.nonzero(ratio < overlap)
    taken_obs, taken_cluster = set(), set()
    for at in np.lexsort((cols, rows, ratio[rows, cols])):
        k, c = int(rows[at]), int(cols[at])
        if k not in taken_obs and c not in taken_cluster:
            clusters[c].append((frame, k))
            taken_obs.add(k)
            taken_cluster.add(c)
    clusters.extend([(frame, k)] for k in range(count) if k not in taken_obs)


def _merge(observations: list[Observations], moved: list[Ellipsoids],
           clusters: list[list[tuple[int, int]]]) -> Observations:
    newest_frame = len(observations) - 1
    newest = observations[newest_frame]
    centers, axes, rotations = [], [], []
    class_ids, instance_ids, embeddings = [], [], []
    with_embeddings = all(frame.image_embeddings is not None for frame in observations if len(frame))
    for cluster in clusters:
        ellipsoids = Ellipsoids(*(np.array([getattr(moved[f], name)[k] for f, k in cluster])
                                  for name in ("centers", "axes", "rotations")))
        center, axis, rotation = _moments(ellipsoids)
        centers.append(center)
        axes.append(axis)
        rotations.append(rotation)
        class_ids.append(_most_frequent([int(observations[f].class_ids[k]) for f, k in cluster]))
        instance_ids.append(_most_frequent([int(observations[f].instance_ids[k]) for f, k in cluster]))
        if with_embeddings:
            mean = np.mean([observations[f].image_embeddings[k] for f, k in cluster], axis=0, dtype=np.float64)
            embeddings.append(mean / max(np.linalg.norm(mean), 1e-12))
    seen = len(newest)  # clusters seeded by the newest frame come first, in its order
    unseen = len(clusters) - seen
    dimension = next((frame.image_embeddings.shape[1] for frame in observations if frame.image_embeddings is not None),
                     0)
    return Observations(
        ellipsoids=Ellipsoids(np.reshape(centers, (-1, 3)), np.reshape(axes, (-1, 3)),
                              np.reshape(rotations, (-1, 3, 3))),
        class_ids=np.array(class_ids, np.int64),
        image_embeddings=np.reshape(embeddings, (-1, dimension)).astype(np.float32) if with_embeddings else None,
        instance_ids=np.array(instance_ids, np.int64),
        detection_index=np.r_[newest.detection_index, np.full(unseen, -1)].astype(np.int64),
        boxes=None if newest.boxes is None else np.r_[np.reshape(newest.boxes, (-1, 4)), np.zeros((unseen, 4))],
        mask_areas=None if newest.mask_areas is None else np.r_[newest.mask_areas, np.zeros(unseen, np.int64)],
        camera=newest.camera,
        has_box=np.r_[np.ones(seen, bool), np.zeros(unseen, bool)],
    )


def _moments(ellipsoids: Ellipsoids) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, semi-axes largest first, rotation) of the members' union by moments; one member as it is."""
    if len(ellipsoids) == 1:
        return ellipsoids.centers[0], ellipsoids.axes[0], ellipsoids.rotations[0]
    center = ellipsoids.centers.mean(axis=0)
    spread = ellipsoids.centers - center
    shapes = np.einsum("nij,nj,nkj->nik", ellipsoids.rotations, ellipsoids.axes**2 / UNIFORM_VARIANCE,
                       ellipsoids.rotations)
    covariance = (shapes + np.einsum("ni,nj->nij", spread, spread)).mean(axis=0)
    variances, rotation = np.linalg.eigh(covariance)
    order = np.argsort(-variances)
    rotation = rotation[:, order]
    if np.linalg.det(rotation) < 0:
        rotation[:, 2] = -rotation[:, 2]
    return center, np.sqrt(UNIFORM_VARIANCE * np.clip(variances[order], 0.0, None)), rotation


def _most_frequent(values: list[int]) -> int:
    """The most frequent value; ties go to the one listed first (the newest member)."""
    unique, first, counts = np.unique(values, return_index=True, return_counts=True)
    best = np.flatnonzero(counts == counts.max())
    return int(unique[best[np.argmin(first[best])]])
