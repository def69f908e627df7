"""The map recording: landmarks, semantic graph, scene geometry and what built them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import scipy.sparse as sp

from clipclique.config import GraphConfig
from clipclique.descriptors.graph import semantic_graph
from clipclique.types import Map
from clipclique.viz.blueprints import map_blueprint
from clipclique.viz.convert import ellipsoids3d, spread_labels, voxel_downsample
from clipclique.viz.recording import RecordingFile
from clipclique.viz.style import annotation_context

SCENE_VOXEL = 0.05  # metres: scene points kept per cell, bounds the file size of large scans
SCENE_MAX_POINTS = 150_000
CEILING_MARGIN = 0.3  # metres above the highest landmark top: scene points higher up are left out
GRAPH_COLOR = (0, 230, 255)  # cyan, in no class colour's shade: it stands out over the scene's points
LABEL_SPACING = 0.8  # metres: a landmark closer than this to a larger labelled one is labelled on hover only
MAP_LEGEND = (
    "**Legend.** Ellipsoids: landmarks in their class colour (the same in every map), labelled where they are "
    "not crowded (hover any for its class, description and instance id). Cyan lines: semantic-graph edges "
    "(centres closer than d_adj)."
)


def graph_edges(centers: np.ndarray, d_adj: float) -> np.ndarray:
    """(E, 2) landmark index pairs (i < j) joined in the semantic graph."""
    rows, cols = sp.triu(semantic_graph(centers, d_adj), k=1).nonzero()
    return np.column_stack((rows, cols)).astype(np.int64)


def below_landmarks(
    map: Map, points: np.ndarray, colors: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Scene points no higher than the landmarks (z-up): the ceiling would hide the room from the
    default view, which looks down from above."""
    if len(map) == 0:
        return points, colors
    top = (map.ellipsoids.centers[:, 2] + map.ellipsoids.axes.max(axis=1)).max() + CEILING_MARGIN
    keep = points[:, 2] <= top
    return points[keep], None if colors is None else colors[keep]


def log_map(stream: rr.RecordingStream, map: Map, d_adj: float) -> None:
    """Static map entities shared by the map and localization recordings."""
    stream.log("/", annotation_context(map.class_names), static=True)
    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    shown = spread_labels(map.ellipsoids.centers, map.ellipsoids.axes.prod(axis=1), LABEL_SPACING)
    labels = [map.class_names[c] if keep else "" for c, keep in zip(map.class_ids, shown)]
    # hover values; rerun warns about an AnyValues with nothing in it, so a map without landmarks has none
    hover = ([rr.AnyValues(description=list(map.descriptions), instance_id=np.asarray(map.instance_ids))] if len(map)
             else [])
    stream.log("world/map/landmarks", ellipsoids3d(map.ellipsoids, map.class_ids, labels=labels), *hover, static=True)
    edges = graph_edges(map.ellipsoids.centers, d_adj)
    stream.log(
        "world/map/graph",
        rr.LineStrips3D(map.ellipsoids.centers[edges], colors=GRAPH_COLOR, radii=rr.Radius.ui_points(2.0)),
        static=True,
    )


def map_summary(map: Map, d_adj: float) -> str:
    classes = np.bincount(map.class_ids, minlength=len(map.class_names))
    rows = "\n".join(f"| {name} | {count} |" for name, count in zip(map.class_names, classes) if count)
    return (
        f"## Map\n\n{len(map)} landmarks, {len(graph_edges(map.ellipsoids.centers, d_adj))} graph edges "
        f"(d_adj = {d_adj} m), text encoder: `{map.encoder}`.\n\n| class | landmarks |\n|---|---|\n{rows}\n"
    )


def write_map_recording(
    path: Path,
    map: Map,
    scene_points: np.ndarray | None,
    scene_colors: np.ndarray | None,
    description: str,
    *,
    d_adj: float = GraphConfig.d_adj,
) -> None:
    """Write `path` (.rrd): landmarks (hover for descriptions), graph edges, the scene downsampled and
    without its ceiling, and `description` (markdown) with a summary of the map."""
    with RecordingFile(path, "clipclique-map", lambda: map_blueprint(map.ellipsoids.centers)) as recording:
        stream = recording.stream
        log_map(stream, map, d_adj)
        if scene_points is not None and len(scene_points):
            points, colors = below_landmarks(map, scene_points, scene_colors)
            points, colors = voxel_downsample(points, colors, SCENE_VOXEL, SCENE_MAX_POINTS)
            scene = rr.Points3D(points, colors=colors, radii=rr.Radius.ui_points(1.0))
            stream.log("world/map/scene", scene, static=True)
        stream.log(
            "description",
            rr.TextDocument(f"{description}\n\n{MAP_LEGEND}\n\n{map_summary(map, d_adj)}",
                            media_type=rr.MediaType.MARKDOWN),
            static=True,
        )
