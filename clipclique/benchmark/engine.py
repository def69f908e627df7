"""The benchmark's engine: (scene, configuration) runs as tasks, in this process or on a Dask cluster.

Per scene and perception key (clipclique.benchmark.perception) the selected frames are perceived once, in
chunks, into the on-disk cache; every run then localizes its frames from the cache in chunks.
Tasks return their frames to this process, which alone writes each run's folder, exactly as
`clipclique-loc run` does (clipclique.localization.run.save_run), once all its chunks are in. A task that
fails is retried once; a run with a failed task is reported (scene, frames, reason), not written.
Runs whose results.json exists are skipped, cached frames are not perceived again: an
interrupted benchmark resumes with the remaining work.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from clipclique.benchmark import perception
from clipclique.datasets import is_bag, resolve_data_root, scene_name
from clipclique.errors import ClipcliqueError, MapFileError, one_line
from clipclique.io.outputs import map_file
from clipclique.localization.results import read_results
from clipclique.localization.run import (
    FrameOutcome,
    Run,
    RunSettings,
    localize_observed,
    note_unannotated,
    observe,
    prepare,
    save_run,
    selected_frames,
)
from clipclique.mapping.run import run_build
from clipclique.multiframe.window import WindowConfig, Windower, window_frames
from clipclique.pipeline import MapIndex, index_map
from clipclique.sim import DEMO_SCENES
from clipclique.types import Ellipsoids, Observations

CHUNK_FRAMES = 16  # frames per task: enough work to outweigh a task's overhead, small enough to spread
RETRIES = 1


class TaskKind(str, Enum):
    PERCEIVE = "perceive"
    LOCALIZE = "localize"


@dataclass(frozen=True)
class Task:
    """One unit of work: perceive or localize `frames` of a scene (for the run named `run`)."""

    kind: TaskKind
    scene: str
    frames: tuple[int, ...]
    run: str | None = None

    def label(self) -> str:
        span = f"frame {self.frames[0]}" if len(self.frames) == 1 else f"frames {self.frames[0]}-{self.frames[-1]}"
        return f"{self.scene}{'' if self.run is None else ' / ' + self.run}, {self.kind.value} {span}"


@dataclass
class TaskFailure:
    task: Task
    reason: str  # one line, naming the frame where it is known


class FrameError(Exception):
    """A task's error, with the scene and frame it happened on (pickles as one string across a cluster)."""


class Tracker(Protocol):
    """What the engine reports as it goes (the CLI draws a progress bar from it)."""

    def start(self, total: int) -> None: ...
    def update(self, done: int, running: int, failed: int) -> None: ...
    def failed(self, failure: TaskFailure) -> None: ...


@dataclass
class Job:
    """One (scene, configuration) run: its settings, as prepared here, and where its frames are cached."""

    run: Run
    frames: list[int]
    cache: Path
    worker_settings: RunSettings  # the settings with absolute paths, for a worker in another folder
    outcomes: dict[int, FrameOutcome | str] = field(default_factory=dict)  # a name: not annotated, left out
    failures: list[TaskFailure] = field(default_factory=list)
    pending: int = 0

    def members(self, frame: int) -> list[int]:
        """The frames localizing `frame` reads: itself, and its window's earlier frames (--window)."""
        settings = self.run.settings
        return [frame] if self.run.odometry is None else window_frames(frame, WindowConfig(settings.window,
                                                                                          settings.window_step))


@dataclass
class BenchResult:
    documents: list[dict[str, Any]]  # written now or found finished, in plan order
    failed: list[dict[str, Any]]  # runs not written: scene, run, reasons
    skipped: int  # runs found finished
    tasks: int  # tasks run now
    wall_s: float


# ---- worker side: module-level functions, each process keeps what it prepared ----

KEPT = 8  # runs (sequence, map, models) and map indexes a worker keeps: a dataset of many scenes must not fill it
_RUNS: OrderedDict[str, Run] = OrderedDict()
_INDEXES: OrderedDict[str, MapIndex] = OrderedDict()


def _memo(store: OrderedDict, key: str, make: Callable[[], Any]) -> Any:
    """`store[key]`, made when missing; the least recently used beyond KEPT are dropped."""
    if key not in store:
        store[key] = make()
    store.move_to_end(key)
    while len(store) > KEPT:
        store.popitem(last=False)
    return store[key]


def _cached_run(settings: RunSettings) -> Run:
    return _memo(_RUNS, _run_key(settings), lambda: prepare(settings))


def _run_key(settings: RunSettings) -> str:
    return json.dumps(dataclasses.asdict(settings), default=str, sort_keys=True)


def perceive_chunk(settings: RunSettings, frames: tuple[int, ...], folder: Path) -> int:
    """Detect, fit and embed each frame not cached yet; the number perceived."""
    run = _cached_run(settings)
    count = 0
    for i in frames:
        path = perception.frame_file(folder, i)
        if path.is_file():
            continue
        try:
            frame = run.sequence[i]
            # as clipclique-loc run: left out, not a failure
            if run.detector.reads_instances and frame.instances is None:
                perception.save_unannotated(path, frame.index, frame.timestamp, frame.name)
            else:
                perception.save(path, frame.index, frame.timestamp, frame.name, frame.pose, observe(run, frame))
        except Exception as error:  # noqa: BLE001  the frame and a one-line reason travel back instead of a traceback
            raise FrameError(f"{run.sequence.name} frame {i}: {type(error).__name__}: {one_line(error)}") from None
        count += 1
    return count


def localize_chunk(settings: RunSettings, frames: tuple[int, ...], folder: Path,
                   *after: Any) -> list[FrameOutcome | str]:
    """Localize and score the cached frames (`after`: the perception tasks they wait for); a frame without
    annotations for the detector is its name."""
    run = _cached_run(settings)
    key = json.dumps([dataclasses.asdict(settings), run.config.to_dict()], default=str, sort_keys=True)
    index = _memo(_INDEXES, key, lambda: index_map(run.map, run.config))
    windower = None if run.odometry is None else Windower(
        WindowConfig(run.settings.window, run.settings.window_step), run.odometry.poses, run.map.class_names)
    outcomes = []
    for i in frames:
        try:
            seen = perception.load(perception.frame_file(folder, i))
            if seen.observations is None:
                outcomes.append(seen.name)
                continue
            query = None
            if windower is not None:  # as clipclique-loc run's localize_window, the earlier frames from the cache
                query = windower.query(i, seen.observations, lambda j: _cached_observations(folder, j))
            observations = seen.observations if query is None else query.observations
            result, evaluation = localize_observed(run, index, observations, seen.gt_pose, seen.index)
        except Exception as error:  # noqa: BLE001
            raise FrameError(f"{run.sequence.name} frame {i}: {type(error).__name__}: {one_line(error)}") from None
        outcomes.append(FrameOutcome(seen.index, seen.timestamp, seen.name, seen.gt_pose, seen.num_detections,
                                     seen.dropped, result, evaluation, seen.timings | result.timings, query))
    return outcomes


def _cached_observations(folder: Path, frame: int) -> Observations:
    """A window's earlier frame from the cache; nothing seen where its detector had no annotations to read."""
    observations = perception.load(perception.frame_file(folder, frame)).observations
    if observations is None:
        empty = np.zeros(0, np.int64)
        return Observations(Ellipsoids.empty(), empty, None, empty, empty)
    return observations


# ---- this process: plan the tasks, run them, write the runs ----

def ensure_map(name: str, data_root: Path | None) -> None:
    """Build a missing demo map as clipclique-map does (the demo data is generated on first use);
    a missing map of any other sequence is the user's to build."""
    path = map_file(scene_name(name))
    if path.is_file():
        return
    if is_bag(Path(name)):
        raise MapFileError(f"{path}: no map for the bag {name} (a bag holds none); build it from the recording's TUM "
                           f"folder (`clipclique-map build FOLDER --out {path}`)")
    if name not in DEMO_SCENES:
        raise MapFileError(f"{path}: no map of {name}; build it with `clipclique-map build {name}`")
    run_build(name, data_root, path, rrd=False)


def finished_results(settings: RunSettings, sequence: str) -> dict[str, Any] | None:
    """The results of a run already written, or None."""
    path = settings.out_dir(sequence) / "results.json"
    if not path.is_file():
        return None
    try:
        return read_results(path)
    except ClipcliqueError:
        return None  # damaged: run it again


def plan_jobs(runs: list[RunSettings], cache_root: Path) -> tuple[list[Job], dict[Path, dict[str, Any]]]:
    """Prepare each run here (maps built for the demo); those not finished yet, and the documents of those that are.

    Tasks run in this process find each run prepared under their settings (`_cached_run`), sharing its sequence,
    map and models instead of loading them a second time (seconds for CLIP and YOLO)."""
    jobs, done = [], {}
    for settings in runs:
        default = map_file(scene_name(settings.sequence))
        if settings.map_path in (None, default):  # --map: the user's map, never built here (a bag's is its default)
            ensure_map(settings.sequence, settings.data_root)
        worker_settings = dataclasses.replace(settings, data_root=resolve_data_root(settings.data_root).resolve(),
                                              map_path=settings.resolved_map_path().resolve(), out=None)
        run = prepare(settings)
        _memo(_RUNS, _run_key(worker_settings),
              lambda run=run, worker_settings=worker_settings: dataclasses.replace(run, settings=worker_settings,
                                                                                   notes=list(run.notes), frames=[],
                                                                                   unannotated=[]))
        document = finished_results(settings, run.sequence.name)
        if document is not None:
            done[settings.out_dir(run.sequence.name)] = document
            continue
        folder = perception.folder_of(cache_root, perception.key_of(run))
        jobs.append(Job(run, list(selected_frames(run)), folder, worker_settings))
    return jobs, done


def chunks(frames: list[int]) -> Iterator[tuple[int, ...]]:
    for start in range(0, len(frames), CHUNK_FRAMES):
        yield tuple(frames[start:start + CHUNK_FRAMES])


def needs_gpu(run: Run) -> bool:
    """The detector or encoder is a model that runs on CUDA here (a device of None: CUDA when there is one)."""
    models = [model for model in (run.detector, run.encoder) if hasattr(model, "device")]
    if not models:
        return False
    import torch  # loaded already: a model with a device is a torch model

    return torch.cuda.is_available() and any(str(model.device or "cuda").startswith("cuda") for model in models)


@dataclass
class Submission:
    task: Task
    function: Callable[..., Any]
    args: tuple[Any, ...]
    gpu: bool
    job: Job | None = None  # a localization task's run
    after: list[Submission] = field(default_factory=list)


def submissions(jobs: list[Job]) -> list[Submission]:
    """Perception chunks of the frames not cached yet (one set per cache folder), then every run's
    localization chunks, each after the perception chunks of its frames."""
    wanted: dict[Path, tuple[Job, set[int]]] = {}
    for job in jobs:
        wanted.setdefault(job.cache, (job, set()))[1].update(i for frame in job.frames for i in job.members(frame))
    perceiving: dict[tuple[Path, int], Submission] = {}
    tasks = []
    for folder, (job, frames) in wanted.items():
        missing = sorted(i for i in frames if not perception.frame_file(folder, i).is_file())
        for chunk in chunks(missing):
            submission = Submission(Task(TaskKind.PERCEIVE, job.run.sequence.name, chunk), perceive_chunk,
                                    (job.worker_settings, chunk, folder), needs_gpu(job.run))
            tasks.append(submission)
            perceiving |= {(folder, i): submission for i in chunk}
    for job in jobs:
        for chunk in chunks(job.frames):
            read = [i for frame in chunk for i in job.members(frame)]
            after = list({id(s): s for i in read if (s := perceiving.get((job.cache, i)))}.values())
            tasks.append(Submission(Task(TaskKind.LOCALIZE, job.run.sequence.name, chunk, job.run.settings.run_name()),
                                    localize_chunk, (job.worker_settings, chunk, job.cache), False, job, after))
            job.pending += 1
    return tasks


def run_jobs(runs: list[RunSettings], cache_root: Path, tracker: Tracker, client: Any = None) -> BenchResult:
    """Run the plan in this process (`client` None) or on a dask.distributed Client's cluster."""
    started = time.perf_counter()
    jobs, done = plan_jobs(runs, cache_root)
    tasks = submissions(jobs)
    tracker.start(len(tasks))
    documents = dict(done)
    results = (_in_process if client is None else _on_cluster)(tasks, tracker, client)
    for submission, value, failure in results:
        job = submission.job
        if job is None:
            continue
        job.pending -= 1
        if failure is not None:
            job.failures.append(failure)
        else:
            job.outcomes |= dict(zip(submission.task.frames, value))
        if job.pending == 0 and not job.failures:
            document = save_run(job.run, lambda run, recorder, job=job: _fill(job, recorder))
            documents[job.run.settings.out_dir(job.run.sequence.name)] = document
    failed = [{"sequence": job.run.sequence.name, "run": job.run.settings.run_name(),
               "reasons": [failure.reason for failure in job.failures]} for job in jobs if job.failures]
    return BenchResult([documents[s.out] for s in runs if s.out in documents], failed, len(done), len(tasks),
                       time.perf_counter() - started)


def _fill(job: Job, recorder: Any) -> None:
    """The run's frames in order; a recording replays each frame with its detections (the detector is
    deterministic) and its cached observations."""
    job.run.detections_file = None  # a model's COCO detections are not cached: no file rather than an empty one
    job.run.frames = [job.outcomes[i] for i in job.frames if not isinstance(job.outcomes[i], str)]
    job.run.unannotated = [job.outcomes[i] for i in job.frames if isinstance(job.outcomes[i], str)]
    note_unannotated(job.run, len(job.frames))
    if recorder is None:
        return
    for outcome in job.run.frames:
        frame = job.run.sequence[outcome.frame_index]
        seen = perception.load(perception.frame_file(job.cache, outcome.frame_index))
        recorder.log_frame(frame, job.run.detector.detect(frame), seen.observations, outcome.result, outcome.evaluation)


Outcome = tuple[Submission, Any, TaskFailure | None]


def _in_process(tasks: list[Submission], tracker: Tracker, client: None) -> Iterator[Outcome]:
    """Each task in order here, retried once; one after a failed task is not run."""
    failed: set[int] = set()
    for done, submission in enumerate(tasks, start=1):
        tracker.update(done - 1, 1, len(failed))
        upstream = next((s for s in submission.after if id(s) in failed), None)
        value, failure = None, None
        if upstream is not None:
            failure = TaskFailure(submission.task, f"not run: {upstream.task.label()} failed")
        else:
            value, failure = _attempt(submission)
        if failure is not None:
            failed.add(id(submission))
            tracker.failed(failure)
        tracker.update(done, 0, len(failed))
        yield submission, value, failure


def _attempt(submission: Submission) -> tuple[Any, TaskFailure | None]:
    """The task's value, or its failure after RETRIES more tries."""
    for _ in range(RETRIES + 1):
        try:
            return submission.function(*submission.args), None
        except Exception as error:  # noqa: BLE001  reported with its task, not raised: the other runs go on
            reason = one_line(error)
    return None, TaskFailure(submission.task, reason)


def _on_cluster(tasks: list[Submission], tracker: Tracker, client: Any) -> Iterator[Outcome]:
    """Every task submitted at once (each retried once by the scheduler), results as they complete."""
    from distributed import as_completed

    futures = {}
    for submission in tasks:
        after = [futures[id(s)] for s in submission.after]
        futures[id(submission)] = client.submit(submission.function, *submission.args, *after, retries=RETRIES,
                                                pure=False, resources={"GPU": 1} if submission.gpu else None,
                                                key=f"{submission.task.kind.value}-{submission.task.label()}-{id(submission)}")
    by_key = {futures[id(s)].key: s for s in tasks}
    done = failures = 0
    workers = max(1, sum(client.nthreads().values()))
    for future in as_completed(list(futures.values())):
        submission = by_key[future.key]
        done += 1
        if future.status == "error":
            error = future.exception()
            failures += 1
            failure = TaskFailure(submission.task, one_line(error))
            tracker.failed(failure)
            yield submission, None, failure
        else:
            yield submission, future.result(), None
        tracker.update(done, min(workers, len(tasks) - done), failures)
        future.release()
