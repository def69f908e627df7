"""Rerun recordings of the map and of every localization stage (one `.rrd` per run).

Entity paths (shared by both recordings, so a map and a run line up when opened together):

- `world/map/landmarks` ellipsoids, class colours, labels; hover shows description and instance id
- `world/map/graph` semantic-graph edges; `world/map/scene` downsampled scene points
- `world/camera/gt` ground-truth camera (Transform3D + Pinhole) holding `rgb` and `detections/{masks,boxes}`
- `depth` the query depth, subsampled, in its own 2D view
- `world/camera/estimate/<rank>` top-N estimated cameras; `world/trajectory/{gt,estimate}`
- `world/observations/{gt,estimate}` observed ellipsoids placed by either pose
- `world/correspondences/candidates`, `world/hypotheses/<rank>` matches, coloured correct or wrong
- `metrics/...` per-frame scalars; `description` the run's text document; `log` per-frame notes
"""

from clipclique.viz.localization_recording import LocalizationRecorder
from clipclique.viz.map_recording import write_map_recording
from clipclique.viz.style import class_colors

__all__ = ["LocalizationRecorder", "class_colors", "write_map_recording"]
