"""Default layouts, so a recording opens showing what a user needs: the scene framed, the camera
with its overlays, the metrics over time and the run's description."""

from __future__ import annotations

import numpy as np
import rerun.blueprint as rrb

MIN_FRAMED_EXTENT = 2.0  # metres: a tiny map is still seen from a sensible distance
EYE_DIRECTION = np.array([-0.4, -0.72, 0.65])  # from a low corner, looking down onto the scene


def framing(centers: np.ndarray) -> rrb.EyeControls3D:
    """An orbit eye that sees every landmark (world frame is z-up)."""
    if len(centers) == 0:
        return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital)
    low, high = centers.min(axis=0), centers.max(axis=0)
    target = (low + high) / 2
    extent = max(float(np.linalg.norm(high - low)), MIN_FRAMED_EXTENT)
    return rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=target + extent * EYE_DIRECTION,
        look_target=target,
        eye_up=[0.0, 0.0, 1.0],
    )


def _panels(timeline: str | None = None) -> list:
    return [
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=timeline),
    ]


def map_blueprint(centers: np.ndarray, hide_graph: bool = False) -> rrb.Blueprint:
    """The map recording's layout; `hide_graph` (the alignment recording) opens the 3D view without the semantic
    graph, whose edges bury the correspondences as they bury the matches of a localization recording."""
    overrides = {"world/map/graph": rrb.EntityBehavior(visible=False)} if hide_graph else None
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="map", origin="world", eye_controls=framing(centers), overrides=overrides),
            rrb.TextDocumentView(name="description", origin="description"),
            column_shares=[3, 1],
        ),
        *_panels(),
    )


def localization_blueprint(centers: np.ndarray) -> rrb.Blueprint:
    """`centers`: what the 3D view must frame (landmarks and ground-truth camera positions)."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(
                    name="3D: map, cameras, matches",
                    origin="world",
                    eye_controls=framing(centers),
                    # a dense map's semantic graph (the desk's: hundreds of edges) would bury the matches;
                    # the map recording shows it, here it is one click away (the eye icon in the blueprint)
                    overrides={"world/map/graph": rrb.EntityBehavior(visible=False)},
                ),
                rrb.TextDocumentView(name="legend", origin="legend"),
                row_shares=[5, 1],
            ),
            rrb.Vertical(
                rrb.Tabs(
                    rrb.Spatial2DView(
                        name="camera + detections",
                        origin="world/camera/gt",
                        contents=["+ $origin/rgb", "+ $origin/detections/**", "+ $origin/projected_landmarks"],
                    ),
                    rrb.Spatial2DView(name="depth", origin="depth"),
                ),
                rrb.Tabs(
                    rrb.TimeSeriesView(name="translation error (m)", origin="metrics/error",
                                       contents=["$origin/translation_m", "$origin/no_pose"]),
                    rrb.TimeSeriesView(name="confidence of the top-1 pose", origin="metrics/confidence"),
                    rrb.TimeSeriesView(name="rotation error (deg)", origin="metrics/error",
                                       contents=["$origin/rotation_deg", "$origin/no_pose"]),
                    rrb.TimeSeriesView(name="counts", origin="metrics/count"),
                    rrb.TimeSeriesView(name="time per stage (s)", origin="metrics/time"),
                    rrb.TimeSeriesView(name="precision / recall", origin="metrics/match"),
                ),
                rrb.Tabs(
                    rrb.TextDocumentView(name="description", origin="description"),
                    rrb.TextLogView(name="frame log", origin="log"),
                ),
                row_shares=[4, 3, 2],
            ),
            column_shares=[3, 2],
        ),
        *_panels(timeline="frame"),
    )
