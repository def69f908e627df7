"""The input options of a localization run, defined once: `clipclique-loc run` and `clipclique-bench` take them
as the same options (these `Annotated` types), and a benchmark plan file as keys of the same names (`PLAN_KEYS`).
The ROS bag options (topics, depth unit, ground truth) are among them: a bag is a sequence to both tools.

Typer reads options off a command's parameters, so each CLI lists them as parameters of these types and hands
them to `RunInputs`, which gives the `RunSettings` fields.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from clipclique.errors import ClipcliqueError

INPUTS, WINDOW, BAG = "Inputs", "Window of frames", "ROS bag"

MapOption = Annotated[Optional[Path], typer.Option(
    "--map", help="map file \\[default: outputs/maps/SEQUENCE.map.npz]", rich_help_panel=INPUTS)]
SamePlaceOption = Annotated[bool, typer.Option(
    "--same-place", help="the map is of another recording of this place: localize against it (poses in the map's "
                         "frame; ground truth scored only if it shares that frame)", rich_help_panel=INPUTS)]
MinScoreOption = Annotated[Optional[float], typer.Option(
    "--min-score", min=0.0, max=1.0, help="drop detections scoring lower (file: and yolo detectors)",
    rich_help_panel=INPUTS)]
LabelsOption = Annotated[Optional[str], typer.Option(
    "--labels", help="coco | lvis | FILE (one class name per line, the 0-based line the id): the label set of a "
                     "--detector file:'s category ids \\[default: coco]", rich_help_panel=INPUTS)]
StrictDetectionsOption = Annotated[bool, typer.Option(
    "--strict-detections", help="refuse a detection file holding an ellipse or box under 1 pixel (default: skip "
                                "them with one warning)", rich_help_panel=INPUTS)]
WindowOption = Annotated[int, typer.Option(
    "--window", min=1, help="localize each frame with the K - 1 frames before it, fused by odometry", metavar="K",
    rich_help_panel=WINDOW)]
WindowStepOption = Annotated[Optional[int], typer.Option(
    "--window-step", min=1, help="the window takes every S-th frame back from the newest \\[default: 1]", metavar="S",
    rich_help_panel=WINDOW)]
WindowSpanOption = Annotated[Optional[float], typer.Option(
    "--window-span", help="the window's K frames spread over this many seconds back from the newest (not "
                                   "with --window-step)", metavar="SECONDS", rich_help_panel=WINDOW)]
OdometryOption = Annotated[Optional[str], typer.Option(
    "--odometry", help="FILE.tum (a metric VO/SLAM trajectory, matched by timestamp; not scale-free monocular) or "
                       "groundtruth (with --odometry-drift, simulated); on a ROS bag also tf:PARENT:CHILD (/tf) or "
                       "topic:/odom (nav_msgs/Odometry)", rich_help_panel=WINDOW)]
OdometryDriftOption = Annotated[float, typer.Option(
    "--odometry-drift", min=0.0, max=100.0, help="simulated drift of --odometry groundtruth, percent of the "
                                                 "distance travelled", metavar="PCT", rich_help_panel=WINDOW)]
# ---- how a ROS bag is read (clipclique.datasets.rosbag.BagOptions) ----
RgbTopicOption = Annotated[Optional[str], typer.Option(
    "--rgb-topic", help="colour topic \\[default: the only colour Image or CompressedImage topic]",
    rich_help_panel=BAG)]
DepthTopicOption = Annotated[Optional[str], typer.Option(
    "--depth-topic", help="depth topic \\[default: the only 32FC1, 16UC1 or compressedDepth topic]",
    rich_help_panel=BAG)]
CameraInfoTopicOption = Annotated[Optional[str], typer.Option(
    "--camera-info-topic", help="CameraInfo topic \\[default: the colour topic's camera_info]", rich_help_panel=BAG)]
DepthScaleOption = Annotated[Optional[float], typer.Option(
    "--depth-scale", help="metres per depth unit \\[default: 32FC1 1, 16UC1 0.001]", rich_help_panel=BAG)]
GroundtruthOption = Annotated[Optional[Path], typer.Option(
    "--groundtruth", help="ground truth of a bag: a TUM trajectory file", rich_help_panel=BAG)]
GtFramesOption = Annotated[Optional[str], typer.Option(
    "--gt-frames", help="ground truth of a bag from /tf: WORLD:CAMERA (static transforms applied)",
    rich_help_panel=BAG)]
BAG_FIELDS = ("rgb_topic", "depth_topic", "camera_info_topic", "depth_scale", "groundtruth", "gt_frames")


def bag_options(rgb_topic: str | None = None, depth_topic: str | None = None, camera_info_topic: str | None = None,
                depth_scale: float | None = None, groundtruth: Path | None = None, gt_frames: str | None = None):
    """The ROS bag options given, None when none is (BagOptions is imported only then: --help stays instant)."""
    given = (rgb_topic, depth_topic, camera_info_topic, depth_scale, groundtruth, gt_frames)
    if all(value is None for value in given):
        return None
    from clipclique.datasets import BagOptions

    return BagOptions(*given)


@dataclass(frozen=True)
class RunInputs:
    """What the shared options were given; the field names are the plan file's keys."""

    map: Path | None = None
    same_place: bool = False
    min_score: float | None = None
    labels: str | None = None
    strict_detections: bool = False
    window: int = 1
    window_step: int | None = None  # None: 1, or what window_span makes of the span
    odometry: str | None = None
    odometry_drift: float = 0.0
    window_span: float | None = None
    rgb_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    depth_scale: float | None = None
    groundtruth: Path | None = None
    gt_frames: str | None = None

    def __post_init__(self) -> None:
        if self.window_span is not None and self.window_step is not None:
            raise ClipcliqueError(f"--window-span {self.window_span:g} and --window-step {self.window_step} are "
                                  "mutually exclusive: give the span (seconds) or the step (frames)")

    def settings(self) -> dict[str, Any]:
        """The `RunSettings` keyword arguments these inputs set."""
        fields = asdict(self)
        fields["map_path"] = fields.pop("map")
        fields["min_score"] = fields["min_score"] or 0.0
        fields["window_step"] = fields["window_step"] or 1
        fields["bag"] = bag_options(**{name: fields.pop(name) for name in BAG_FIELDS})
        return fields


# plan key -> (TOML type, how the value becomes a RunInputs field)
PLAN_KEYS: dict[str, tuple[type, Any]] = {
    "map": (str, Path), "same_place": (bool, bool), "min_score": (float, float), "labels": (str, str),
    "strict_detections": (bool, bool), "window": (int, int), "window_step": (int, int), "odometry": (str, str),
    "odometry_drift": (float, float), "window_span": (float, float), "rgb_topic": (str, str),
    "depth_topic": (str, str), "camera_info_topic": (str, str), "depth_scale": (float, float),
    "groundtruth": (str, Path), "gt_frames": (str, str),
}
