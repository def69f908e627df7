"""The localization recording: every stage of every frame on the timeline `frame`, so a user can
see where a failing frame lost the right answer (detections, observations, candidates, cliques, pose)."""

from __future__ import annotations

import math
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from clipclique.config import GraphConfig
from clipclique.types import Detections, Ellipsoids, Frame, Map, Observations, Pose
from clipclique.verify.projection import box_iou, ellipse_outlines, project
from clipclique.viz.blueprints import localization_blueprint
from clipclique.viz.convert import (
    box_fields,
    camera,
    camera_columns,
    camera_row,
    depth_fields,
    ellipsoid_fields,
    image_fields,
    rgb_fields,
    segmentation,
    with_quaternions,
)
from clipclique.viz.map_recording import log_map, map_summary
from clipclique.viz.recording import ArchetypeRows, ColumnsAtClose, RecordingFile, Worker, queued
from clipclique.viz.style import (
    ESTIMATE_CAMERA,
    GT_CAMERA,
    WRONG,
    annotation_ids,
    correctness_colors,
    match_correctness,
)

if TYPE_CHECKING:
    from clipclique.metrics import FrameEvaluation
    from clipclique.multiframe.window import WindowQuery
    from clipclique.pipeline import LocalizationResult

CAMERA = "world/camera/gt"  # holds the query image and overlays, so they hang in the ground-truth frustum
DEPTH = "depth"  # outside `world`: subsampled (see convert), shown in its own 2D view, not projected
UNIX_TIME_MIN = 1e9  # TUM stamps are Unix seconds (> 2001); ScanNet's are frame numbers
WINDOW_SOURCES = "world/window/sources"  # a fused window's source observations (window localization)
WINDOW_PATH = "world/window/odometry"  # ... and its cameras by odometry
WINDOW_COLOR = (120, 120, 255)
GT_FRUSTUM_M = 0.4
ESTIMATE_FRUSTUM_M = 0.25
LOWER_RANK_ALPHA = 110  # top-1 estimate opaque, the rest of the top-N faded
TRAJECTORY_POINTS = 300  # trajectories are drawn whole at each frame, thinned to this many points
NO_POSE = "metrics/error/no_pose"  # a red cross at 0 on the error plots for each frame without a pose
ERRORS = ("metrics/error/translation_m", "metrics/error/rotation_deg")  # cleared (a gap) where there is none
LEGEND = (
    "**White** ground truth: camera, trajectory, observations placed by it · **Yellow** the top-1 estimate "
    "(ranks 2-5 faded), observations placed by it · **Lines** thin: candidate matches, thick: an estimated "
    "camera's clique; green correct, red wrong, grey no ground-truth object · **Dots** top-1 positions so far, "
    "green within 1 m · **Ellipsoids** landmarks in class colours (hover for any label) · **Cyan** semantic-graph "
    "edges, hidden at first (show `world/map/graph` in the blueprint panel) · **Camera** detection boxes labelled "
    "where they do not crowd (hover the rest), projected landmarks of the top-1 pose with the IoU of those "
    "supporting it · **Error plots** a gap and a red cross where a frame has no pose · **Blue** (window "
    "localization) the window's source observations, older frames darker, and its cameras by odometry"
)


def with_correctness_colors(fields: dict) -> dict:
    """`fields` with their `correct` (match_correctness codes) as colours: green, red or grey."""
    colors = correctness_colors(fields.pop("correct"))
    return fields | {"colors": colors}


# how the rows kept until close become columns (see ArchetypeRows)
ELLIPSOIDS = ArchetypeRows(rr.Ellipsoids3D, ("centers", "half_sizes", "rotations", "class_ids", "colors", "labels"),
                           convert=with_quaternions)
BOXES = ArchetypeRows(rr.Boxes2D, ("centers", "half_sizes", "class_ids", "labels"))
MATCHES = ArchetypeRows(rr.LineStrips3D, ("strips", "correct"), convert=with_correctness_colors)  # one radius a row
PATHS = ArchetypeRows(rr.LineStrips3D, ("strips",))  # one colour and radius a row
OUTLINES = ArchetypeRows(rr.LineStrips2D, ("strips", "class_ids", "labels", "radii"))
SIMILARITIES = ArchetypeRows(rr.AnyValues, ("similarity",))
SOURCE_FRAMES = ArchetypeRows(rr.AnyValues, ("frame",))
CLIQUE_VALUES = ArchetypeRows(rr.AnyValues)
ENCODED_IMAGES = ArchetypeRows(rr.EncodedImage)
DEPTH_IMAGES = ArchetypeRows(rr.DepthImage)
SEGMENTATION_IMAGES = ArchetypeRows(rr.SegmentationImage)
IMAGES_PER_SEND = 10  # frames of images sent as one column each (about 4 MB of a VGA frame's)


class LocalizationRecorder:
    """Writes one `.rrd` for a localization run; use as a context manager or call `close`.

    `log_frame` only queues the frame: a thread of the recorder's own encodes and logs it, so the
    recording costs the localization loop next to nothing. Call `flush` to wait for it. Only the ground-truth camera
    goes to the stream frame by frame; the images (rgb, depth, detection masks) go every IMAGES_PER_SEND frames, and
    the rest (detection boxes, estimated cameras, placed observations, matches and cliques, the projected landmarks,
    trajectories, metrics, text log, clears) at `close`, each as plain fields until then and one column per entity
    and component when sent: that thread (and the GIL the run needs) is spared building Rerun's objects every frame
    (see ColumnsAtClose and ArchetypeRows), and a viewer sees the same values at the same frames.
    """

    def __init__(self, path: Path, map: Map, description: str, *, d_adj: float = GraphConfig.d_adj) -> None:
        self.map = map
        self._ranks_shown = 0  # hypotheses drawn by some earlier frame
        self._gt_positions: list[np.ndarray] = []
        self._estimate_positions: list[np.ndarray] = []  # top-1 of each frame with a pose
        self._estimate_correct: list[int] = []  # match_correctness code of each estimate
        self._late = ColumnsAtClose()  # all but the images and the ground-truth camera: sent at close
        self._images = ColumnsAtClose()  # sent every IMAGES_PER_SEND frames
        self._now: tuple[int, float | None] = (0, None)  # the frame being logged and its timestamp (None: not Unix)
        self._recording = RecordingFile(path, "clipclique-loc", self._blueprint)
        self.stream = self._recording.stream
        log_map(self.stream, map, d_adj)
        self.stream.log("legend", rr.TextDocument(LEGEND, media_type=rr.MediaType.MARKDOWN), static=True)
        self.stream.log(NO_POSE, rr.SeriesPoints(colors=WRONG, markers="cross", names="no pose", marker_sizes=4.0),
                        static=True)
        self.stream.log(
            "description",
            rr.TextDocument(f"{description}\n\n{map_summary(map, d_adj)}", media_type=rr.MediaType.MARKDOWN),
            static=True,
        )
        self._worker = Worker("clipclique-recording")

    def flush(self) -> None:
        """Wait until every queued frame is logged."""
        self._worker.drain()

    @queued
    def log_frame(
        self,
        frame: Frame,
        detections: Detections,
        observations: Observations,
        result: LocalizationResult,
        evaluation: FrameEvaluation | None,
    ) -> None:
        """Log one localized frame (queued: see the class); `evaluation` is None without ground truth. The
        arguments must not change afterwards (the run loop makes new ones every frame)."""
        self.stream.set_time("frame", sequence=frame.index)
        if frame.timestamp >= UNIX_TIME_MIN:
            self.stream.set_time("time", timestamp=frame.timestamp)
        self._now = (frame.index, frame.timestamp if frame.timestamp >= UNIX_TIME_MIN else None)
        top1 = result.hypotheses[0].pose if result.hypotheses else None
        self._log_images(frame, detections)
        self._log_cameras(frame, result, evaluation)
        self._log_observations(observations, frame.pose, top1)
        self._log_matches(observations, result, frame.pose or top1)
        self._log_projection(observations, result)
        self._log_metrics(frame, observations, result, evaluation)
        self._log_text(frame, observations, result, evaluation)
        self._ranks_shown = max(self._ranks_shown, len(result.hypotheses))

    @queued
    def log_window(self, query: WindowQuery, placement: Pose | None) -> None:
        """(Queued after the frame it belongs to, so it lands at that frame's time.) The fused window of the frame just
        logged: each source frame's observations moved into the newest camera (newest brightest, older ones fading) and
        the odometry path of the window's cameras, placed by
        `placement` (the ground truth, else the top-1 estimate)."""
        if placement is None:
            for path in (WINDOW_SOURCES, WINDOW_PATH):
                self._late.clear(path, *self._now)
            return
        moved = query.fusion.moved
        ages = np.repeat(np.arange(len(moved))[::-1], [len(e) for e in moved])  # 0 = the newest frame
        shade = np.clip(255 - 40 * ages, 60, 255).astype(np.uint8)
        stacked = Ellipsoids(*(np.concatenate([getattr(e, name) for e in moved]).reshape(shape)
                               for name, shape in (("centers", (-1, 3)), ("axes", (-1, 3)), ("rotations", (-1, 3, 3)))))
        classes = np.concatenate([sources.class_ids for sources in query.fusion.sources]).astype(np.int64)
        self._late.add(WINDOW_SOURCES, *self._now, ellipsoid_fields(stacked.transformed(placement), classes,
                                                          colors=np.column_stack((shade // 2, shade // 2, shade)),
                                                          fill_mode="MajorWireframe", show_labels=False), ELLIPSOIDS)
        self._late.add(WINDOW_SOURCES, *self._now, {"frame": np.repeat(query.frames, [len(e) for e in moved])},
                       SOURCE_FRAMES)
        cameras = placement.apply(np.array([pose.translation for pose in query.poses]))
        self._late.add(WINDOW_PATH, *self._now,
                       {"strips": [cameras], "colors": WINDOW_COLOR, "radii": rr.Radius.ui_points(2.0)}, PATHS)

    def close(self) -> None:
        try:
            self._worker.stop()
            self._images.send(self.stream)
            self._late.send(self.stream)
        except BaseException:
            self._recording.abort()
            raise
        self._recording.close()

    def __enter__(self) -> LocalizationRecorder:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        if kind is None:
            self.close()
        else:
            self._worker.stop(discard=True)
            self._recording.abort()

    def _blueprint(self) -> rrb.Blueprint:
        """The default layout, its 3D view framing the landmarks and the ground-truth trajectory."""
        return localization_blueprint(np.vstack([self.map.ellipsoids.centers, *self._gt_positions]))

    def _log_images(self, frame: Frame, detections: Detections) -> None:
        height, width = frame.rgb.shape[:2]
        self.stream.log(CAMERA, *camera(frame.pose, frame.intrinsics, width, height, GT_CAMERA, GT_FRUSTUM_M))
        self._images.add(f"{CAMERA}/rgb", *self._now, rgb_fields(frame.rgb), ENCODED_IMAGES)
        self._images.add(DEPTH, *self._now, depth_fields(frame.depth), DEPTH_IMAGES)
        masks = image_fields(segmentation(detections, (height, width))) | {"opacity": 0.45, "draw_order": 1.0}
        self._images.add(f"{CAMERA}/detections/masks", *self._now, masks, SEGMENTATION_IMAGES)
        self._images.send(self.stream, full=IMAGES_PER_SEND)
        labelled, crowded = box_fields(detections, self.map.class_names)
        self._late.add(f"{CAMERA}/detections/boxes", *self._now, labelled, BOXES)
        self._late.add(f"{CAMERA}/detections/crowded_boxes", *self._now, crowded, BOXES)

    def _log_cameras(self, frame: Frame, result: LocalizationResult, evaluation: FrameEvaluation | None) -> None:
        height, width = frame.rgb.shape[:2]
        for rank, hypothesis in enumerate(result.hypotheses, start=1):
            color = np.append(ESTIMATE_CAMERA, 255 if rank == 1 else LOWER_RANK_ALPHA)
            self._late.add(f"world/camera/estimate/{rank}", *self._now,
                           camera_row(hypothesis.pose, frame.intrinsics, width, height, color, ESTIMATE_FRUSTUM_M),
                           camera_columns)
        self._clear_ranks("world/camera/estimate", len(result.hypotheses))

        if frame.pose is not None:
            self._gt_positions.append(frame.pose.translation)
            path = np.array(self._gt_positions)[sample_indices(len(self._gt_positions))]
            self._late.add("world/trajectory/gt", *self._now, path, gt_trajectory_columns)
        if result.hypotheses:
            success = evaluation.success.get(1) if evaluation is not None else None
            self._estimate_positions.append(result.hypotheses[0].pose.translation)
            self._estimate_correct.append(-1 if success is None else int(success))
            keep = sample_indices(len(self._estimate_positions))
            self._late.add("world/trajectory/estimate", *self._now,
                           (np.array(self._estimate_positions)[keep], np.array(self._estimate_correct)[keep]),
                           estimate_trajectory_columns)

    def _log_observations(self, observations: Observations, truth: Pose | None, estimate: Pose | None) -> None:
        labels = [self.map.class_names[c] for c in observations.class_ids]
        for name, pose, color in (("gt", truth, GT_CAMERA), ("estimate", estimate, ESTIMATE_CAMERA)):
            path = f"world/observations/{name}"
            if pose is None or len(observations) == 0:
                self._late.clear(path, *self._now)
                continue
            placed = observations.ellipsoids.transformed(pose)
            colors = np.broadcast_to(color, (len(observations), 3))
            # labels on hover only: the landmarks carry the visible ones
            self._late.add(path, *self._now, ellipsoid_fields(placed, observations.class_ids, labels, colors,
                                                              "MajorWireframe", show_labels=False), ELLIPSOIDS)

    def _log_matches(self, observations: Observations, result: LocalizationResult, placement: Pose | None) -> None:
        """Candidates run from each observation (placed by ground truth, else the top-1 estimate) to its
        landmark, so a correct match is short and green and a wrong one long and red. Each top-N
        hypothesis fans out from its estimated camera to the landmarks of its clique."""
        landmarks = self.map.ellipsoids.centers
        candidates = np.asarray(result.candidates, dtype=np.int64).reshape(-1, 2)
        if placement is None or len(candidates) == 0:
            self._late.clear("world/correspondences/candidates", *self._now)
        else:
            observed = placement.apply(observations.ellipsoids.centers)
            obs, lm = candidates.T
            correct = match_correctness(observations.instance_ids[obs], self.map.instance_ids[lm])
            self._late.add("world/correspondences/candidates", *self._now,
                           {"strips": np.stack((observed[obs], landmarks[lm]), axis=1),
                            "correct": correct, "radii": rr.Radius.ui_points(1.5)}, MATCHES)
            self._late.add("world/correspondences/candidates", *self._now,
                           {"similarity": np.asarray(result.candidate_scores, dtype=np.float64)}, SIMILARITIES)
        for rank, hypothesis in enumerate(result.hypotheses, start=1):
            obs, lm = np.asarray(hypothesis.correspondences, dtype=np.int64).reshape(-1, 2).T
            correct = match_correctness(observations.instance_ids[obs], self.map.instance_ids[lm])
            origin = np.broadcast_to(hypothesis.pose.translation, (len(lm), 3))
            self._late.add(f"world/hypotheses/{rank}", *self._now,
                           {"strips": np.stack((origin, landmarks[lm]), axis=1), "correct": correct,
                            "radii": rr.Radius.ui_points(2.5 if rank == 1 else 1.0)}, MATCHES)
            self._late.add(f"world/hypotheses/{rank}", *self._now,
                           {"score": float(hypothesis.score), "correct": int((correct == 1).sum()), "size": len(lm)},
                           CLIQUE_VALUES)
        self._clear_ranks("world/hypotheses", len(result.hypotheses))

    def _log_projection(self, observations: Observations, result: LocalizationResult) -> None:
        """The map projected into the image under the top-1 pose: an ellipse outline per landmark in view,
        in its class colour; those supporting the pose labelled with the IoU with their detection (the detection's
        box names the class), the others on hover."""
        path = f"{CAMERA}/projected_landmarks"
        if not result.hypotheses or observations.camera is None:
            self._late.clear(path, *self._now)
            return
        pose = result.hypotheses[0].pose
        seen = project(self.map.ellipsoids, pose.rotation[None], pose.translation[None], observations.camera)
        shown = np.flatnonzero(seen.visible[0])
        supporting = dict(map(tuple, np.asarray(result.hypotheses[0].correspondences)[:, ::-1].tolist()))
        boxed = np.ones(len(observations), bool) if observations.has_box is None else observations.has_box
        labels = [""] * len(shown)
        labelled = [(k, supporting[landmark]) for k, landmark in enumerate(shown.tolist())
                    if landmark in supporting and boxed[supporting[landmark]]] if observations.boxes is not None else []
        if labelled:  # one box_iou for all of them
            rows, observed = np.array(labelled).T
            for k, iou in zip(rows.tolist(), box_iou(observations.boxes[observed], seen.boxes[0, shown[rows]])):
                labels[k] = f"IoU {iou:.2f}"
        self._late.add(path, *self._now, {
            "strips": ellipse_outlines(seen.dual_conics[0, shown]),
            "class_ids": annotation_ids(self.map.class_ids[shown]),
            "labels": labels,
            "radii": rr.Radius.ui_points(np.where(np.isin(shown, list(supporting)), 2.0, 1.0)),
            "draw_order": 2.0,
        }, OUTLINES)

    def _log_metrics(
        self, frame: Frame, observations: Observations, result: LocalizationResult, evaluation: FrameEvaluation | None
    ) -> None:
        """Kept until `close`, which sends each series as one column (see ColumnsAtClose)."""
        scalars: dict[str, float] = {
            "count/observations": len(observations),
            "count/candidates": len(result.candidates),
            "count/cliques": result.num_cliques,
            "count/hypotheses": len(result.hypotheses),
        }
        scalars |= {f"time/{stage}": seconds for stage, seconds in result.timings.items()}
        if result.hypotheses and result.hypotheses[0].confidence is not None:
            scalars["confidence/top1"] = result.hypotheses[0].confidence
            scalars["verification/top1"] = result.hypotheses[0].verification
        if evaluation is not None:
            if evaluation.translation_error is not None:
                scalars["error/translation_m"] = evaluation.translation_error
                scalars["error/rotation_deg"] = math.degrees(evaluation.rotation_error)
            if evaluation.precision is not None:
                scalars["match/precision"] = evaluation.precision
            scalars["match/recall"] = evaluation.recall
        for name, value in scalars.items():
            self._late.scalar(f"metrics/{name}", *self._now, value)
        if "error/translation_m" not in scalars:  # no line drawn across a frame without a pose
            for path in ERRORS:
                self._late.clear(path, *self._now)
            if not result.hypotheses:
                self._late.scalar(NO_POSE, *self._now, 0.0)

    def _log_text(
        self,
        frame: Frame,
        observations: Observations,
        result: LocalizationResult,
        evaluation: FrameEvaluation | None,
    ) -> None:
        line = (
            f"frame {frame.index} {frame.name}: {len(observations)} observations, "
            f"{len(result.candidates)} candidates, {result.num_cliques} cliques"
        )
        if evaluation is not None and evaluation.translation_error is not None:
            line += (
                f"; top-1 TE {evaluation.translation_error:.2f} m, "
                f"RE {math.degrees(evaluation.rotation_error):.1f} deg"
            )
        lines = [(line, rr.TextLogLevel.INFO)]
        if result.failure is not None:
            lines.append((f"no pose: {result.failure.message}", rr.TextLogLevel.WARN))
        if result.cap_hit is not None:
            lines.append((f"bound hit: {result.cap_hit}", rr.TextLogLevel.WARN))
        lines += [(note, rr.TextLogLevel.INFO) for note in result.notes]
        for text_line in lines:
            self._late.add("log", *self._now, text_line, text_log_columns)

    def _clear_ranks(self, parent: str, shown: int) -> None:
        """Remove ranks a previous frame drew but this one has no hypothesis for."""
        for rank in range(shown + 1, self._ranks_shown + 1):
            self._late.clear(f"{parent}/{rank}", *self._now, recursive=True)


def text_log_columns(lines: list[tuple[str, str]]) -> list[rr.ComponentColumn]:
    """Text log lines (text, level), one row each."""
    texts, levels = zip(*lines)
    return list(rr.TextLog.columns(text=texts, level=levels))


def gt_trajectory_columns(paths: list[np.ndarray]) -> list[rr.ComponentColumn]:
    """The ground-truth trajectory so far at each frame: one strip a row."""
    return list(rr.LineStrips3D.columns(strips=paths, colors=[GT_CAMERA] * len(paths)))


def estimate_trajectory_columns(rows: list[tuple[np.ndarray, np.ndarray]]) -> list[rr.ComponentColumn]:
    """The top-1 positions so far at each frame (positions, match_correctness codes), coloured by correctness."""
    positions, codes = zip(*rows)
    points = rr.Points3D.columns(positions=np.concatenate(positions),
                                 colors=correctness_colors(np.concatenate(codes))).partition([len(p)
                                                                                              for p in positions])
    return [*points, *rr.Points3D.columns(radii=[rr.Radius.ui_points(4.0)] * len(rows))]


def sample_indices(count: int, limit: int = TRAJECTORY_POINTS) -> np.ndarray:
    """Indices of at most `limit` of `count` trajectory points, evenly spread, first and last kept:
    a trajectory re-logged every frame then costs O(frames), not O(frames^2)."""
    return np.unique(np.linspace(0, count - 1, min(count, limit)).round().astype(np.int64))
