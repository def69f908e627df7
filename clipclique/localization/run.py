"""The runner of `clipclique-loc run`: read the sequence and map, then frames -> detections ->
observations -> poses -> metrics, then write the results (`run_and_save`, what the CLI, the demo and
the tests call).

Every frame is scored, including those with too few observations (they count as failures).
Which detector and encoder ran, and whether they are simulated, travels with the results.
"""

from __future__ import annotations

import math
import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import closing
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from clipclique.backends import load_encoder, make_detector
from clipclique.commands import command
from clipclique.config import LocalizationConfig, ObservationParams, make_config
from clipclique.datasets import Sequence, is_bag
from clipclique.datasets.rosbag import NO_DETECTOR
from clipclique.errors import ClipcliqueError, MapFileError, ModelUnavailableError
from clipclique.interop.coco import reported_classes
from clipclique.interop.detections import CocoRecorder, FileDetector
from clipclique.interop.labels import COCO, label_set, met_by
from clipclique.io.mapfile import load_map
from clipclique.io.outputs import Staging
from clipclique.localization.results import (
    DETECTIONS_FILE,
    IMAGES_FILE,
    OUTPUT_FILES,
    RECORDING,
    earlier_recording,
    run_description,
    write_results,
)
from clipclique.localization.runs import FrameOutcome, Run, RunProgress, RunSettings
from clipclique.metrics import FrameEvaluation, evaluate_frame
from clipclique.multiframe.odometry import GROUND_TRUTH, Odometry, open_odometry
from clipclique.multiframe.window import WindowConfig, Windower, span_step
from clipclique.perception.detectors import Detector
from clipclique.perception.encoders import Encoder
from clipclique.perception.observations import embed, extract_observations
from clipclique.perception.yolo import YoloDetector
from clipclique.pipeline import LocalizationResult, MapIndex, index_map, localize
from clipclique.resolve import check_scene, default_detector, open_scene
from clipclique.types import Detections, Ellipsoids, Frame, Map, Observations, Pose

if TYPE_CHECKING:
    from clipclique.viz import LocalizationRecorder  # rerun is imported only when a run records



def prepare(settings: RunSettings) -> Run:
    """Open the sequence and map, choose the detector and encoder (none when the descriptor does not use
    CLIP), settle the config."""
    config = make_config(settings.method, settings.config_file, settings.overrides)
    if settings.map_path is None and is_bag(Path(settings.sequence)):
        raise MapFileError(f"{settings.sequence}: a ROS bag holds no map; pass --map FILE.map.npz (a map of the place, "
                           f"e.g. `{command('clipclique-map')} build` of its TUM folder)")
    map_path = settings.resolved_map_path()
    if not map_path.exists():
        if settings.map_path is not None:
            raise MapFileError(f"--map {map_path}: no such map file")
        check_scene(settings.sequence, settings.data_root)  # a misspelt scene: its own error, not "build it"
        raise MapFileError(f"{map_path}: no map of {settings.sequence} yet; build it with "
                           f"`{command('clipclique-map')} build {settings.sequence}` (or pass --map PATH)")
    map = load_map(map_path)
    sequence = open_scene(settings.sequence, settings.data_root, bag=settings.bag)
    notes: list[str] = sequence.notes()
    check_map_source(map, map_path, sequence.name, settings, notes)
    if gap := sequence.missing_poses():
        notes.append(f"{gap}; those frames cannot be scored")
    map = met_by_detections(map, settings.detector or default_detector(sequence), settings.labels, notes)
    detector = choose_detector(settings, sequence, map, notes)
    encoder = choose_query_encoder(settings, config, map, sequence, notes)
    check_encoder(config, encoder, map, str(map_path), settings.method, notes)
    if isinstance(detector, FileDetector):
        notes += detector.meet_by_text(encoder)
    recorder = None
    if isinstance(detector, YoloDetector):  # its detections, so that `--detector file:` reruns without GPU or weights
        recorder = CocoRecorder(map.class_names, reported_classes(detector.class_map, map.class_names))
    settings = with_window_span(settings, sequence)
    return Run(settings, config, sequence, map, detector, encoder, notes,
               detections_file=recorder, odometry=window_odometry(settings, sequence))


def choose_detector(settings: RunSettings, sequence: Sequence, map: Map, notes: list[str]) -> Detector:
    """The `--detector` asked, else the sequence's default (`default_detector`), made for the map's classes; a
    detection file's coverage of the selected frames goes into `notes`."""
    detector_kind = settings.detector or default_detector(sequence)
    if detector_kind == NO_DETECTOR:
        raise ClipcliqueError(f"{settings.sequence}: a ROS bag has no annotations to detect from; pass --detector "
                              "file:DETECTIONS.json (e.g. a TUM folder run's, matched by colour stamp) "
                              "or --detector yolo")
    detector = make_detector(detector_kind, sequence.object_classes(), map.class_names, settings.yolo_weights,
                             settings.seed, settings.min_score, settings.labels,
                             settings.strict_detections)
    if isinstance(detector, FileDetector):
        notes += detector.check_coverage(sequence, frame_selection(settings, len(sequence)))
    elif settings.labels is not None:
        raise ClipcliqueError(f"--labels {settings.labels}: only a --detector file: reads category ids")
    return detector


def met_by_detections(map: Map, detector_kind: str, labels: str | None, notes: list[str]) -> Map:
    """The map as the detections of `--detector detector_kind` meet it (`clipclique.interop.labels.met_by`: COCO
    detections, of a file read in `labels` or of YOLO, against an LVIS map), what changed going into `notes`; the
    detector is then made for the map's classes as met."""
    if detector_kind.startswith("file:"):
        label_names = label_set(labels)
    elif detector_kind == "yolo":
        label_names = COCO
    else:
        return map
    map, note = met_by(map, label_names)
    notes += note
    return map


def choose_query_encoder(settings: RunSettings, config: LocalizationConfig, map: Map, sequence: Sequence | None,
                         notes: list[str]) -> Encoder | None:
    """The encoder the query crops need (`choose_encoder`); none when the descriptor does not read CLIP."""
    if config.similarity.descriptor in ("clip", "fused"):
        return choose_encoder(settings.encoder, map, notes, sequence)
    if settings.encoder not in (None, "none"):  # SH and X-View never read CLIP: no model to load, no crops to embed
        notes.append(f"--encoder {settings.encoder} not used: the {config.similarity.descriptor} descriptor "
                     "does not read CLIP")
    return None


def check_encoder(config: LocalizationConfig, encoder: Encoder | None, map: Map, map_name: str, method: str,
                  notes: list[str]) -> None:
    """Without CLIP embeddings on either side, "clip" is refused and "fused" falls back to SH (alpha = 0, noted)."""
    if config.similarity.descriptor == "clip" and (encoder is None or map.text_embeddings is None):
        missing = "no encoder is available" if encoder is None else f"{map_name} has no text embeddings"
        raise ModelUnavailableError(f"method {method} ranks by CLIP alone but {missing}; pass --encoder "
                                    "(e.g. open_clip:ViT-L-14/openai) or choose --method clipclique / sh / xview")
    if config.similarity.descriptor == "fused" and (encoder is None or map.text_embeddings is None):
        config.similarity.alpha = 0.0
        notes.append("no CLIP embeddings: alpha = 0 (Semantic Histograms only)")


def with_window_span(settings: RunSettings, sequence: Sequence) -> RunSettings:
    """`--window-span SECONDS` as the window step that spreads the K frames over it (`span_step`); the settings
    as they are without a span. A span and a step are mutually exclusive."""
    span = settings.window_span
    if span is None:
        return settings
    if settings.window_step != 1:
        raise ClipcliqueError(f"--window-span {span:g} and --window-step {settings.window_step} are mutually "
                              "exclusive: give the span (seconds) or the step (frames)")
    if not math.isfinite(span) or span <= 0:
        raise ClipcliqueError(f"--window-span {span:g}: expected a positive number of seconds")
    if settings.window < 2:
        raise ClipcliqueError(f"--window-span {span:g} needs --window K (K > 1)")
    return replace(settings, window_step=span_step(span, settings.window, sequence.trajectory()[0]))


def window_odometry(settings: RunSettings, sequence: Sequence) -> Odometry | None:
    """The odometry a window needs (None without a window); refusals say which option is missing."""
    if settings.window < 1 or settings.window_step < 1:
        raise ClipcliqueError(f"--window {settings.window} --window-step {settings.window_step}: "
                              "both must be 1 or more")
    if settings.window == 1:
        if settings.odometry is not None or settings.odometry_drift:
            raise ClipcliqueError("--odometry and --odometry-drift need --window K (K > 1)")
        return None
    if settings.odometry is None:
        on_bag = ", or from the bag: tf:PARENT:CHILD or topic:/odom" if sequence.kind == "rosbag" else ""
        raise ClipcliqueError(f"--window {settings.window} needs --odometry FILE.tum (a metric trajectory) or "
                              f"--odometry {GROUND_TRUTH} (with --odometry-drift PCT, simulated){on_bag}")
    timestamps, truth = sequence.trajectory()
    return open_odometry(settings.odometry, settings.odometry_drift, settings.seed, timestamps, truth, sequence)


def check_map_source(map: Map, map_path: Path, sequence_name: str, settings: RunSettings, notes: list[str]) -> None:
    """A map of another recording: meant (`--same-place`: noted, with what its poses are) or an accident
    (refused: poses in another place's frame would be meaningless)."""
    source = map.provenance.get("source", {}).get("name")
    if source is None or source == sequence_name:
        return
    if not settings.same_place:
        raise ClipcliqueError(f"{map_path}: a map of {source}, not of {sequence_name}; if {sequence_name} is another "
                              f"recording of the place {source} shows, pass --same-place; else build its own map "
                              f"(`{command('clipclique-map')} build {settings.sequence}`)")
    notes.append(f"the map is of {source}, another recording of this place (--same-place): poses are in its frame, "
                 f"and {sequence_name}'s ground truth scores them only if it shares that frame")


def choose_encoder(spec: str | None, map: Map, notes: list[str], sequence: Sequence | None = None) -> Encoder | None:
    """The requested encoder, else the one that made the map's text embeddings when it is here, else none
    (a simulated one knows the descriptions of `sequence`)."""
    if spec is None:
        if map.text_embeddings is None:
            return None
        try:
            return load_encoder(map.encoder, scene=sequence)
        except ModelUnavailableError as error:
            notes.append(f"the map's encoder is not available here ({error})")
            return None
    encoder = load_encoder(spec, scene=sequence)
    if encoder is not None and map.text_embeddings is not None and map.encoder != encoder.name:
        raise ClipcliqueError(f"the map's text embeddings come from {map.encoder} but the query encoder is "
                              f"{encoder.name}; their embeddings are not comparable (pass --encoder {map.encoder})")
    return encoder


@dataclass
class Seen:
    """One frame's detections and observations, and what producing them cost."""

    detections: Detections
    observations: Observations
    dropped: dict[str, int]
    timings: dict[str, float]  # seconds, outcomes.QUERY_STAGES


def observe(run: Run, frame: Frame) -> Seen:
    """Detect, fit observed ellipsoids (`config.observations`), embed their crops (`observe_with`)."""
    return observe_with(run.detector, run.encoder, run.config.observations, frame, run.detections_file)


def observe_with(detector: Detector, encoder: Encoder | None, params: ObservationParams, frame: Frame,
                 detections_file: CocoRecorder | None = None) -> Seen:
    """One frame detected, its observed ellipsoids fitted (`params`) and their crops embedded, each step timed;
    the detections also go to `detections_file` when given."""
    timings: dict[str, float] = {}
    clock = time.perf_counter()
    detections = detector.detect(frame)
    timings["detector"] = time.perf_counter() - clock
    if detections_file is not None:
        detections_file.add(frame, detections)
    clock = time.perf_counter()
    extraction = extract_observations(frame, detections, params)
    timings["observations"] = time.perf_counter() - clock
    clock = time.perf_counter()
    observations = embed(extraction, encoder)
    timings["encoder"] = time.perf_counter() - clock
    return Seen(detections, observations, extraction.dropped, timings)


def localize_frame(run: Run, frame: Frame, index: MapIndex) -> tuple[FrameOutcome, Seen]:
    """Observe, localize and score one frame."""
    seen = observe(run, frame)
    result, evaluation = localize_observed(run, index, seen.observations, frame.pose, frame.index)
    outcome = FrameOutcome(frame.index, frame.timestamp, frame.name, frame.pose, len(seen.detections), seen.dropped,
                           result, evaluation, seen.timings | result.timings)
    return outcome, seen


def localize_observed(run: Run, index: MapIndex, observations: Observations, gt_pose: Pose | None,
                      frame_index: int) -> tuple[LocalizationResult, FrameEvaluation]:
    """Localize one frame's observations and score the result against its ground truth."""
    result = localize(observations, index, run.config)
    return result, evaluate_frame(result, observations, run.map, gt_pose, run.config, frame_index)


def selected_frames(run: Run) -> range:
    return frame_selection(run.settings, len(run.sequence))


def frame_selection(settings: RunSettings, length: int) -> range:
    """The frame indices a run localizes (--stride, --max-frames); an error when none."""
    selected = range(0, length, settings.stride)[:settings.max_frames]
    if not selected:
        raise ClipcliqueError(f"{settings.sequence}: no frames selected ({length} frames, "
                              f"stride {settings.stride}, max {settings.max_frames})")
    return selected


def localize_window(run: Run, frame: Frame, index: MapIndex, windower: Windower) -> tuple[FrameOutcome, Seen]:
    """Observe the frame, fuse its window (earlier frames observed when no earlier query did), localize, score."""
    seen = observe(run, frame)
    query = windower.query(frame.index, seen.observations, lambda i: earlier_observations(run, run.sequence[i]))
    result = localize(query.observations, index, run.config)
    evaluation = evaluate_frame(result, query.observations, run.map, frame.pose, run.config, frame.index)
    outcome = FrameOutcome(frame.index, frame.timestamp, frame.name, frame.pose, len(seen.detections), seen.dropped,
                           result, evaluation, seen.timings | result.timings, query)
    return outcome, seen


def earlier_observations(run: Run, frame: Frame) -> Observations:
    """A window's earlier frame observed; nothing seen where the detector reads an instance image the frame lacks."""
    if run.detector.reads_instances and frame.instances is None:
        empty = np.zeros(0, np.int64)
        return Observations(Ellipsoids.empty(), empty, None, empty, empty)
    return observe(run, frame).observations


def execute(run: Run, recorder: LocalizationRecorder | None = None,
            progress: Callable[[RunProgress], None] | None = None) -> Run:
    """Localize the selected frames (each with its window when asked); log each to `recorder` when given.
    Frames are read ahead on a thread (`read_ahead`), except with a window, whose earlier frames the loop reads too."""
    index = index_map(run.map, run.config)
    selected = selected_frames(run)
    windower = None if run.odometry is None else Windower(
        WindowConfig(run.settings.window, run.settings.window_step), run.odometry.poses, run.map.class_names)
    frames = (run.sequence[i] for i in selected) if windower is not None else read_ahead(run.sequence, selected)
    span = recording_span(run.sequence, selected)
    with closing(frames):
        for count, frame in enumerate(frames, start=1):
            localize_one(run, frame, index, windower, recorder)
            if progress is not None:
                progress(RunProgress(count, len(selected), span and (frame.timestamp - span[0], span[1] - span[0])))
    note_unannotated(run, len(selected))
    return run


def recording_span(sequence: Sequence, selected: range) -> tuple[float, float] | None:
    """A bag's first and last selected colour stamps (its index holds them); None for a folder, whose reader may
    decode every frame to know them."""
    if sequence.kind != "rosbag":
        return None
    stamps = sequence.trajectory()[0]
    return float(stamps[selected[0]]), float(stamps[selected[-1]])


def read_ahead(sequence: Sequence, selected: range, ahead: int = 2) -> Iterator[Frame]:
    """The selected frames in order, each read on a thread while the caller works on the frames before it:
    decoding the PNG and JPEG files (Pillow releases the GIL) overlaps detection and localization. A read's
    error is raised where its frame is reached; closing the iterator cancels the reads not started."""
    pool = ThreadPoolExecutor(1, thread_name_prefix="clipclique-read")
    try:
        pending = deque(pool.submit(sequence.__getitem__, i) for i in selected[:ahead])
        for i in selected[ahead:]:
            frame = pending.popleft().result()
            pending.append(pool.submit(sequence.__getitem__, i))
            yield frame
        while pending:
            yield pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def localize_one(run: Run, frame: Frame, index: MapIndex, windower: Windower | None,
                 recorder: LocalizationRecorder | None) -> None:
    """Localize one frame (with its window when there is one) into `run.frames`, logged to `recorder`."""
    if run.detector.reads_instances and frame.instances is None:  # not annotated: nothing to detect, not a failure
        run.unannotated.append(frame.name)
        return
    outcome, seen = (localize_frame(run, frame, index) if windower is None
                     else localize_window(run, frame, index, windower))
    run.frames.append(outcome)
    if recorder is not None:
        observations = seen.observations if outcome.window is None else outcome.window.observations
        recorder.log_frame(frame, seen.detections, observations, outcome.result, outcome.evaluation)
        if outcome.window is not None:
            top1 = outcome.result.hypotheses[0].pose if outcome.result.hypotheses else None
            recorder.log_window(outcome.window, frame.pose or top1)


def note_unannotated(run: Run, selected: int) -> None:
    """The frames left out for want of annotations, as a note; none annotated at all is an error."""
    if run.unannotated:
        shown = ", ".join(run.unannotated[:3]) + (", ..." if len(run.unannotated) > 3 else "")
        if not run.frames:
            raise ClipcliqueError(f"{run.sequence.root}: none of the {selected} frames selected has annotations "
                                  f"for --detector {run.detector.name} to read (e.g. {shown})")
        run.notes.append(f"{len(run.unannotated)} of {selected} frames have no annotations for the "
                         f"{run.detector.name} detector: left out, not counted as failures ({shown})")


def run_and_save(settings: RunSettings, progress: Callable[[RunProgress], None] | None = None) -> dict[str, Any]:
    """Prepare, localize every selected frame, write results (and the .rrd) into
    `settings.out_dir(sequence name)`; the results document."""
    return save_run(prepare(settings), lambda run, recorder: execute(run, recorder, progress))


def save_run(run: Run, fill: Callable[[Run, LocalizationRecorder | None], object]) -> dict[str, Any]:
    """`fill(run, recorder)` puts the frames into `run` (logging each to the recorder when the run records);
    then the results are written into `run.settings.out_dir(sequence name)`; the results document.
    (`run_and_save` localizes here; the benchmark fills in frames localized elsewhere.)

    The outputs appear together once the run succeeded; a failed or interrupted run leaves the
    previous ones as they were and no folder it made empty behind. Without a recording (--no-rrd), an
    earlier run's recording.rrd is left as it is: a user's file is never removed as a side effect; when it
    shows other results, results.json and a note say so.
    """
    settings = run.settings
    out_dir = settings.out_dir(run.sequence.name)
    made = [folder for folder in (out_dir, *out_dir.parents) if not folder.exists()]  # deepest first
    recording = out_dir / RECORDING
    earlier = None if settings.record else earlier_recording(out_dir)
    try:
        writable_folder(out_dir)
        with Staging() as staging:
            partials = {name: staging.path(out_dir / name) for name in OUTPUT_FILES}  # a folder in the way: refused now
            if settings.record:
                from clipclique.viz import LocalizationRecorder

                with LocalizationRecorder(staging.path(recording), run.map, recording_description(run),
                                          d_adj=run.config.graph.d_adj) as recorder:
                    fill(run, recorder)
            else:
                fill(run, None)
            document = write_results(run, partials, earlier)
            if run.detections_file is not None:
                run.detections_file.write(staging.path(out_dir / DETECTIONS_FILE), staging.path(out_dir / IMAGES_FILE))
            staging.commit()
        return document
    except BaseException:
        for folder in made:
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        raise


def writable_folder(out_dir: Path) -> Path:
    """`out_dir`, created; a folder that cannot be written is a user error before the run, not a
    traceback after it."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ClipcliqueError(f"--out {out_dir}: cannot create the folder ({error.strerror})") from None
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise ClipcliqueError(f"--out {out_dir}: the folder is not writable")
    return out_dir


def recording_description(run: Run) -> str:
    """The recording's text document: what ran, flagged where simulated, and the settings changed from the
    method's preset (the full configuration is config.json beside the recording: a JSON block would fill the
    panel with its first brace)."""
    description = run_description(run)
    parts = [f"# {description['method_title']} on {description['sequence']}",
             f"- map: `{description['map']}` (text embeddings: {description['map_encoder']})"]
    for role in ("detector", "encoder"):
        part = description[role]
        parts.append(f"- {role}: none" if part is None else
                     f"- {role}: {part['name']}{' — **simulated**' if part['simulated'] else ''}")
    if run.odometry is not None:
        span = "" if run.settings.window_span is None else f" (spread over {run.settings.window_span:g} s)"
        parts.append(f"- window: {run.settings.window} frames, step {run.settings.window_step}{span}; odometry: "
                     f"{run.odometry.name}{' — **simulated**' if run.odometry.simulated else ''}")
    parts += [f"- note: {note}" for note in run.notes]
    changed = description["changed"]
    parts.append("- settings changed from the preset: " + (", ".join(f"`{k} = {v}`" for k, v in changed.items())
                                                          if changed else "none"))
    parts.append("- full configuration: `config.json` beside this recording")
    return "\n".join(parts)
