"""The map-alignment recording: both maps overlaid, the query map placed by each candidate transform."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from clipclique.config import GraphConfig
from clipclique.multiframe.mapalign import MapAlignment
from clipclique.types import Map
from clipclique.viz.blueprints import map_blueprint
from clipclique.viz.convert import ellipsoids3d
from clipclique.viz.map_recording import log_map
from clipclique.viz.recording import RecordingFile

QUERY_COLOR = (255, 140, 0)  # orange: the query map's landmarks, whatever their class
MATCH_COLOR = (60, 220, 60)
ALIGN_LEGEND = (
    "**Legend.** Ellipsoids in class colours: the map. Orange ellipsoids: the query map placed by a candidate "
    "transform (`world/candidates/1` is the best; the others are hidden-able entities of their own). Green "
    "lines: the candidate's correspondences."
)


def write_alignment_recording(path: Path, query_map: Map, map: Map, alignment: MapAlignment, description: str,
                              *, d_adj: float = GraphConfig.d_adj) -> None:
    """Write `path` (.rrd): the map, the query map under every candidate transform with its correspondences,
    and `description` (markdown)."""
    placed = [query_map.ellipsoids.transformed(c.pose) for c in alignment.candidates]
    framed = np.concatenate([map.ellipsoids.centers, *(e.centers for e in placed[:1])]).reshape(-1, 3)
    with RecordingFile(path, "clipclique-align", lambda: map_blueprint(framed, hide_graph=True)) as recording:
        stream = recording.stream
        log_map(stream, map, d_adj)
        labels = [query_map.class_names[c] for c in query_map.class_ids]
        for rank, (candidate, ellipsoids) in enumerate(zip(alignment.candidates, placed), start=1):
            base = f"world/candidates/{rank}"
            stream.log(f"{base}/query_map", ellipsoids3d(ellipsoids, query_map.class_ids, labels=labels,
                                                         colors=np.tile(QUERY_COLOR, (len(ellipsoids), 1)),
                                                         show_labels=False), static=True)
            pairs = candidate.correspondences
            strips = np.stack((ellipsoids.centers[pairs[:, 0]], map.ellipsoids.centers[pairs[:, 1]]), axis=1)
            stream.log(f"{base}/correspondences", rr.LineStrips3D(strips, colors=MATCH_COLOR,
                                                                  radii=rr.Radius.ui_points(2.0)), static=True)
        stream.log("description", rr.TextDocument(f"{description}\n\n{ALIGN_LEGEND}", media_type=rr.MediaType.MARKDOWN),
                   static=True)
