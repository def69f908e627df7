"""What a run of `clipclique-loc run` is: what it was asked (`RunSettings`), what it carries (`Run`), each
frame's outcome (`FrameOutcome`) and how far it got (`RunProgress`). The runner (run.py) fills them; the
results writer (results.py) reads them."""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path

from clipclique.config import LocalizationConfig, changed_by_overrides
from clipclique.datasets import BagOptions, Sequence, scene_name
from clipclique.interop.detections import CocoRecorder
from clipclique.io.outputs import LOC_DIR, map_file
from clipclique.metrics import FrameEvaluation, summarize
from clipclique.multiframe.odometry import Odometry
from clipclique.multiframe.window import WindowQuery
from clipclique.outcomes import LocalizationResult
from clipclique.perception.detectors import Detector
from clipclique.perception.encoders import Encoder
from clipclique.types import Map, Pose

MAX_RUN_NAME = 100  # characters of a run folder's name; longer ones end in a hash


@dataclass
class RunSettings:
    """Everything `clipclique-loc run` was asked; defaults follow the dataset."""

    sequence: str
    method: str = "clipclique"
    config_file: Path | None = None
    overrides: list[str] = field(default_factory=list)
    map_path: Path | None = None  # default outputs/maps/<SEQUENCE>.map.npz
    data_root: Path | None = None
    # default: the generated scene's (simulated, demo_desk: simulated-yolo), gt on ScanNet, annotations on TUM
    detector: str | None = None
    encoder: str | None = None  # default: the map's encoder (simulated on the demo) if here, else none
    yolo_weights: str = "yolov8x-seg.pt"
    stride: int = 1
    max_frames: int | None = None
    out: Path | None = None  # default outputs/loc/<sequence name>/<run_name()>
    record: bool = True
    seed: int = 0  # the simulated detector's (and the simulated odometry drift's)
    same_place: bool = False  # the map is of another recording of this place (else such a map is refused)
    min_score: float = 0.0  # detections scoring lower are dropped (file: and yolo detectors)
    labels: str | None = None  # --labels: the label set of a detection file's ids (coco, lvis or a names file)
    strict_detections: bool = False  # refuse a detection file with degenerate entries instead of skipping them
    window: int = 1  # K: localize each frame with the K - 1 before it (every window_step-th), fused by odometry
    window_step: int = 1
    window_span: float | None = None  # seconds the K frames spread over (instead of window_step; run.with_window_span)
    odometry: str | None = None  # "groundtruth" or a TUM trajectory file; needed with window > 1
    odometry_drift: float = 0.0  # percent, simulated on ground truth
    bag: BagOptions | None = None  # how a ROS bag is read (topics, depth unit, ground truth); None: chosen

    def out_dir(self, sequence_name: str) -> Path:
        """`--out`, else outputs/loc/<the sequence's resolved name>/<run_name()>."""
        return self.out or LOC_DIR / sequence_name / self.run_name()

    def run_name(self) -> str:
        """The method, then every setting given that changes the results (`clipclique+inliers.d_comp=0.4`, however
        the --set was spelled; one repeating the preset's value is left out): two ablations never share a folder,
        and the same command again replaces its own (identical) results."""
        parts = [self.method]
        if self.config_file is not None:  # the file's content, not just its name, decides the results
            content = self.config_file.read_bytes() if self.config_file.is_file() else b""
            parts.append(f"{self.config_file.stem}-{hashlib.sha1(content).hexdigest()[:6]}")
        parts += [f"{key}={value}" for key, value in
                  changed_by_overrides(self.method, self.config_file, self.overrides).items()]
        given = {"map": self.map_path and self.map_path.name.removesuffix(".map.npz"), "detector": self.detector,
                 "encoder": self.encoder, "stride": self.stride if self.stride != 1 else None,
                 "yolo": Path(self.yolo_weights).stem if self.detector == "yolo" else None,
                 "max_frames": self.max_frames, "min_score": self.min_score or None,
                 "labels": self.labels and Path(self.labels).stem}
        if self.bag is not None:
            given |= {"rgb": self.bag.rgb_topic, "depth": self.bag.depth_topic,
                      "depth_scale": self.bag.depth_scale}
        if self.window > 1:
            given |= {"window": self.window, "window_step": self.window_step if self.window_step != 1 and
                      self.window_span is None else None, "window_span": self.window_span,
                      "odometry": Path(self.odometry).name if self.odometry else None,
                      "drift": self.odometry_drift or None}
        parts += [f"{key}={value}" for key, value in given.items() if value is not None]
        name = re.sub(r"[^\w.,=+-]", "_", "+".join(parts))
        return (name if len(name) <= MAX_RUN_NAME
                else f"{name[:MAX_RUN_NAME - 9]}-{hashlib.sha1(name.encode()).hexdigest()[:8]}")

    def resolved_map_path(self) -> Path:
        return self.map_path or map_file(scene_name(self.sequence))


@dataclass(frozen=True)
class RunProgress:
    """Frames done of the selected ones, and the recording time reached: a bag's progress is its time."""

    done: int
    total: int
    bag_time: tuple[float, float] | None = None  # a bag's: seconds reached since its first frame selected, of span

    def describe(self) -> str:
        """`bag time 12.3 / 45.6 s` for a bag, else nothing (the bar counts the frames)."""
        return "" if self.bag_time is None else f"bag time {self.bag_time[0]:.1f} / {self.bag_time[1]:.1f} s"


@dataclass
class FrameOutcome:
    frame_index: int
    timestamp: float
    name: str
    gt_pose: Pose | None
    num_detections: int
    dropped: dict[str, int]
    result: LocalizationResult
    evaluation: FrameEvaluation
    timings: dict[str, float]  # seconds: outcomes.ALL_STAGES
    window: WindowQuery | None = None  # the fused window this frame was localized with (--window)


@dataclass
class Run:
    settings: RunSettings
    config: LocalizationConfig
    sequence: Sequence
    map: Map
    detector: Detector
    encoder: Encoder | None
    notes: list[str]  # run-wide facts the user must see (alpha forced to 0, the map's encoder missing, ...)
    frames: list[FrameOutcome] = field(default_factory=list)
    unannotated: list[str] = field(default_factory=list)  # frames left out: no instance image to detect from
    detections_file: CocoRecorder | None = None  # a model's detections, kept to be written as COCO results
    odometry: Odometry | None = None  # with a window

    def summary(self) -> dict[str, object]:
        return summarize([outcome.evaluation for outcome in self.frames]) | {"not_annotated": len(self.unannotated)}
