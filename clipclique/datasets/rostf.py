"""A bag's `/tf` tree: the pose of one frame in another at given times, static transforms applied.

Every `TransformStamped` of `/tf` is one sample of an edge parent -> child (child-to-parent pose); those of
`/tf_static` hold for all time. The pose of CHILD in PARENT at time t chains the edges along the tree's path
between them (walked up or down, inverted when walked down), each dynamic edge taken at its sample nearest
to t within `max_diff` (TUM's association rule; no interpolation); a time with no sample that near on some
edge has no pose.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from clipclique.errors import DatasetError
from clipclique.types import Pose


def frame_id(name: str) -> str:
    """A tf frame name as compared: ROS 1's leading slash dropped (`/world` is `world`)."""
    return str(name).strip().lstrip("/")


def transform_pose(transform: object) -> Pose:
    """A geometry_msgs/Transform (or Pose: position, orientation) as a Pose."""
    t = getattr(transform, "translation", None) or transform.position
    q = getattr(transform, "rotation", None) or transform.orientation
    quat = np.array([q.x, q.y, q.z, q.w], np.float64)
    if not np.isfinite(quat).all() or np.linalg.norm(quat) < 1e-6:
        raise ValueError("not a unit quaternion")
    return Pose(Rotation.from_quat(quat).as_matrix(), np.array([t.x, t.y, t.z], np.float64))


@dataclass
class Edge:
    """Samples of one parent -> child transform."""

    times: list[float] = field(default_factory=list)
    poses: list[Pose] = field(default_factory=list)
    static: bool = False

    def at(self, times: np.ndarray, max_diff: float) -> list[Pose | None]:
        if self.static:
            return [self.poses[-1]] * len(times)
        from clipclique.datasets.tum import associate

        nearest = associate(times, np.array(self.times), max_diff)
        return [self.poses[k] if k >= 0 else None for k in nearest]


class TfTree:
    """The edges of a bag's `/tf` and `/tf_static`, added message by message."""

    def __init__(self) -> None:
        self.edges: dict[tuple[str, str], Edge] = defaultdict(Edge)
        self.parent: dict[str, str] = {}

    def add(self, message: object, static: bool, where: str) -> None:
        """The transforms of one tf2_msgs/TFMessage; one that is no rigid transform is a DatasetError."""
        for stamped in message.transforms:
            parent, child = frame_id(stamped.header.frame_id), frame_id(stamped.child_frame_id)
            try:
                pose = transform_pose(stamped.transform)
            except ValueError as problem:
                raise DatasetError(f"{where}: transform {parent} -> {child}: {problem}") from None
            edge = self.edges[parent, child]
            edge.static |= static
            edge.times.append(stamp_seconds(stamped.header.stamp))
            edge.poses.append(pose)
            self.parent.setdefault(child, parent)

    def frames(self) -> set[str]:
        return {name for edge in self.edges for name in edge}

    def path(self, parent: str, child: str) -> list[tuple[Edge, bool]]:
        """The edges from `parent` down to `child` as (edge, inverted); DatasetError when they are not connected."""
        up_from = {name: self._ancestors(name) for name in (parent, child)}
        common = next((name for name in up_from[child] if name in up_from[parent]), None)
        if common is None:
            known = ", ".join(sorted(self.frames())) or "none"
            raise DatasetError(f"/tf does not connect {parent} to {child} (frames in /tf and /tf_static: {known})")
        down = up_from[child][: up_from[child].index(common) + 1][::-1]  # common ... child
        up = up_from[parent][: up_from[parent].index(common) + 1]  # parent ... common
        steps = [(self.edges[self.parent[a], a], True) for a in up[:-1]]
        return steps + [(self.edges[a, b], False) for a, b in zip(down, down[1:])]

    def _ancestors(self, name: str) -> list[str]:
        chain = [name]
        while chain[-1] in self.parent and len(chain) <= len(self.parent):
            chain.append(self.parent[chain[-1]])
        return chain

    def poses(self, parent: str, child: str, times: np.ndarray, max_diff: float) -> list[Pose | None]:
        """The pose of `child` in `parent` at each of `times` (None where an edge has no sample near enough)."""
        parent, child = frame_id(parent), frame_id(child)
        out: list[Pose | None] = [Pose(np.eye(3), np.zeros(3))] * len(times)
        for edge, inverted in self.path(parent, child):
            samples = edge.at(np.asarray(times, np.float64), max_diff)
            out = [
                None if a is None or b is None else a.compose(b.inverse() if inverted else b)
                for a, b in zip(out, samples)
            ]
        return out


def stamp_seconds(stamp: object) -> float:
    """A ROS time (sec, nanosec) in seconds."""
    return int(stamp.sec) + int(stamp.nanosec) * 1e-9
