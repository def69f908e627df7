"""Per-stage speed of a whole frame, the working tree beside a git revision and the literal reference, in one run.

    .venv/bin/python tools/bench_speed.py [SCENE ...] [--rev REV] [--max-frames 40] [--repeat 3]
                                          [--clutter 47 4700 47000] [--clutter-frames 20] [--cpu CORE]

Two worker processes, one importing the working tree and one a `git archive` of `--rev` (default:
the merge base with main), measure the same frames in lock step (frame i in one, then in the
other), so both see the same machine load (`--cpu CORE`: both on one core, as a VM's cores can
differ). Each worker runs the sequence's own detector (once), the observation stage, the encoder
and `localize` (fastest of `--repeat`, per stage) and, in the working tree's worker, the literal
reference (`clipclique.benchmark.literal_reference`, networkx) on the same observations. Printed per scene:
median and 90th percentile ms per stage, before and now, the observation stage per detection, and
the literal reference's whole query beside the project's.

`--recording FRAMES`: the Rerun recording of the first scene, ms of `log_frame` on the caller's
thread per frame, the seconds `close` waits for what is still queued, the CPU seconds of the recorder's
own thread (Python building Rerun's objects, under the GIL the run needs), and kB per frame.

`--whole-runs N`: N whole `clipclique-loc run` processes of the first scene per tree, alternating,
with and without the recording (process start included, after one warm-up run each): wall seconds, and
the CPU seconds (user + system, all threads) that a loaded machine's wall time hides.

`--clutter COUNTS`: the desk scene of `clipclique.benchmark.core` (26 observations a query, the desk map
copied into rooms 20 m apart), SH only, per landmark count: `index_map` seconds (its first call on that
map, numba's one-time process initialisation already paid: that is printed apart), whole-query median
and 90th percentile ms, cap hits, and the worker's peak resident memory; the literal reference at
47 landmarks only (it takes seconds beyond).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# one BLAS thread, as clipclique-loc runs (clipclique.blas), set here: the --rev worker imports another tree
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

TOOLS = Path(__file__).resolve().parent
ROOT = TOOLS.parent
LITERAL_UP_TO = 100  # landmarks: the literal reference's cliques explode on larger clutter maps


def layout_module(name: str):
    """`clipclique.<name>`, or the top-level `<name>` of a tree from before the runners moved into clipclique (told
    by the loaded clipclique's folder: an editable install would find the moved module in this tree instead)."""
    import importlib

    import clipclique

    moved = (Path(clipclique.__file__).parent / name.split(".")[0]).is_dir()
    return importlib.import_module(f"clipclique.{name}" if moved else name)


class Worker:
    """This script in `--worker` mode under another PYTHONPATH, answering one JSON line per request."""

    def __init__(self, tree: Path, label: str, core: int | None = None) -> None:
        environment = dict(os.environ, PYTHONPATH=os.pathsep.join(dict.fromkeys((str(tree), str(ROOT)))))  # the
        # tree's clipclique and localization first; the benchmark package (literal reference) from this one
        self.label = label
        self.process = subprocess.Popen([sys.executable, __file__, "--worker"], cwd=ROOT, env=environment,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        if core is not None:  # both workers on one core: they take turns (lock step), and cores differ
            os.sched_setaffinity(self.process.pid, {core})

    def ask(self, **request) -> dict:
        self.process.stdin.write(json.dumps(request) + "\n")
        self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:
            raise SystemExit(f"bench_speed: the {self.label} worker died (its error is above)")
        return json.loads(line)

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait()


def serve() -> None:
    """Worker mode: requests on stdin, one JSON answer per line on stdout."""
    try:  # a revision from before clipclique.sim: its synthetic maps where this tree's tools import them
        import clipclique.sim.synthetic  # noqa: F401
    except ImportError:
        import types

        import clipclique.synthetic
        sys.modules["clipclique.sim"] = types.ModuleType("clipclique.sim")
        sys.modules["clipclique.sim.synthetic"] = clipclique.synthetic
    literal_reference = layout_module("benchmark.literal_reference")
    from clipclique.pipeline import index_map, localize
    run_module = layout_module("localization.run")
    RunSettings, observe, prepare, selected_frames = (getattr(run_module, name) for name in (
        "RunSettings", "observe", "prepare", "selected_frames"))

    numba_start = numba_start_seconds()  # first, so that no figure below carries it
    runs: dict[str, tuple] = {}
    rooms: dict[int, tuple] = {}
    answer = sys.stdout
    sys.stdout = sys.stderr  # nothing but answers on the pipe
    for line in sys.stdin:
        request = json.loads(line)
        if request["kind"] == "scene":
            scene = request["scene"]
            if scene not in runs:
                run = prepare(RunSettings(scene, max_frames=request["max_frames"], record=False))
                runs[scene] = (run, index_map(run.map, run.config), list(selected_frames(run)))
            run, index, frames = runs[scene]
            if request.get("frame") is None:
                reply = {"frames": len(frames)}
            else:
                frame = run.sequence[frames[request["frame"]]]
                seen = observe(run, frame)
                reply = {f"{stage} ms": 1e3 * seconds for stage, seconds in seen.timings.items()}
                reply |= observation_times(run, frame, seen.detections, request["repeat"])
                reply["detections"] = len(seen.detections)
                reply |= query_times(lambda: localize(seen.observations, index, run.config), request["repeat"])
                reply["observations"] = len(seen.observations)
                if request["literal"]:
                    alpha = run.config.similarity.alpha if run.config.similarity.descriptor == "fused" else 0.0
                    reply["literal ms"] = fastest(lambda: literal_reference.localize(
                        seen.observations, run.map, alpha=alpha), request["repeat"])
        elif request["kind"] == "numba":
            reply = {"numba start s": numba_start}
        elif request["kind"] == "recording":
            reply = recording_times(request["scene"], request["max_frames"], Path(request["out"]))
        else:
            count = request["landmarks"]
            if count not in rooms:
                rooms[count] = clutter_rooms(count, request["scene"])
            config, map, index, index_seconds, queries = rooms[count]
            observations = queries[request["query"]]
            reply = query_times(lambda: localize(observations, index, config), request["repeat"])
            reply |= {"landmarks": len(map), "index s": index_seconds, "observations": len(observations),
                      "peak MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
            if request["literal"] and len(map) <= LITERAL_UP_TO:
                reply["literal ms"] = fastest(lambda: literal_reference.localize(observations, map, alpha=0.0), 1)
        answer.write(json.dumps(reply) + "\n")
        answer.flush()


def numba_start_seconds() -> float:
    """Seconds of the process's first compiled call, a trivial function loaded from numba's cache: numba's one-time
    initialisation (its registries, some 0.2 s), which whatever compiled call a process makes first pays."""
    from numba import njit

    start = time.perf_counter()
    njit(cache=True)(_identity)(0)
    return time.perf_counter() - start


def _identity(value: int) -> int:
    return value


def recording_times(scene: str, max_frames: int, path: Path) -> dict:
    """ms of each `log_frame` on the caller's thread, seconds of the closing `close` (what was still
    queued), and the CPU seconds of the recorder's own thread (what it takes from the run's GIL), for a
    recording of the scene's frames."""
    from clipclique.pipeline import index_map
    from clipclique.viz import LocalizationRecorder
    run_module = layout_module("localization.run")
    RunSettings, localize_frame, prepare, selected_frames = (getattr(run_module, name) for name in (
        "RunSettings", "localize_frame", "prepare", "selected_frames"))

    run = prepare(RunSettings(scene, max_frames=max_frames))
    index = index_map(run.map, run.config)
    calls = []
    with LocalizationRecorder(path, run.map, "bench") as recorder:
        for i in selected_frames(run):
            frame = run.sequence[i]
            outcome, seen = localize_frame(run, frame, index)
            start = time.perf_counter()
            recorder.log_frame(frame, seen.detections, seen.observations, outcome.result, outcome.evaluation)
            calls.append(1e3 * (time.perf_counter() - start))
        start = time.perf_counter()
        recorder.flush()
        thread_seconds = time.clock_gettime(time.pthread_getcpuclockid(recorder._worker._thread.ident))
    closing = time.perf_counter() - start
    return {"log_frame ms": calls, "close s": closing, "thread CPU s": thread_seconds,
            "kB per frame": path.stat().st_size / 1e3 / len(calls)}


def clutter_scene(queries: int = 100, seed: int = 0) -> dict:
    """The desk scene of clipclique.benchmark.core and `queries` queries of it, as JSON both trees' workers read
    (so a revision from before today's modules gets the very same scene)."""
    from clipclique.benchmark.core import ROOM_SPACING, desk_map, desk_query

    base = desk_map(np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    shapes = lambda e: {"centers": e.centers.tolist(), "axes": e.axes.tolist(),  # noqa: E731
                        "rotations": e.rotations.tolist()}
    return {"gap": ROOM_SPACING - float(np.ptp(base.ellipsoids.centers[:, 0])),
            "map": shapes(base.ellipsoids) | {"class_ids": base.class_ids.tolist(), "class_names": base.class_names,
                                              "descriptions": base.descriptions,
                                              "instance_ids": base.instance_ids.tolist()},
            "queries": [shapes(q.ellipsoids)
                        | {"class_ids": q.class_ids.tolist(), "instance_ids": q.instance_ids.tolist()}
                        for q in (desk_query(base, rng) for _ in range(queries))]}


def clutter_rooms(count: int, scene: dict) -> tuple:
    """(config, the desk map copied into rooms 20 m apart, its index, index_map seconds, the queries)."""
    from clipclique.config import make_config
    from clipclique.pipeline import index_map
    from clipclique.sim.synthetic import duplicate_rooms
    from clipclique.types import Ellipsoids, Map, Observations

    ellipsoids = lambda d: Ellipsoids(  # noqa: E731
        *(np.array(d[key], float) for key in ("centers", "axes", "rotations")))
    desk = scene["map"]
    base = Map(ellipsoids(desk), np.array(desk["class_ids"]), desk["class_names"], desk["descriptions"],
               np.array(desk["instance_ids"]), provenance={"simulated": True})
    config = make_config("clipclique", overrides={"similarity.descriptor": "sh"})
    map = duplicate_rooms(base, max(1, count // len(base)), gap=scene["gap"])
    start = time.perf_counter()
    index = index_map(map, config)
    index_seconds = time.perf_counter() - start
    queries = [Observations(ellipsoids(q), np.array(q["class_ids"]), None, np.array(q["instance_ids"]),
                            np.arange(len(q["class_ids"]))) for q in scene["queries"]]
    return config, map, index, index_seconds, queries


def fastest(call, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    return 1e3 * best


def observation_times(run, frame, detections, repeat: int) -> dict:
    """ms of the observation stage and of the encoder on the frame's detections, each the fastest of
    `repeat` (the detector, the slowest stage and no concern of this measure, runs once)."""
    from clipclique.perception.observations import embed, extract_observations

    best = {"observations ms": np.inf, "encoder ms": np.inf}
    for _ in range(repeat):
        start = time.perf_counter()
        extraction = extract_observations(frame, detections, run.config.observations)
        middle = time.perf_counter()
        embed(extraction, run.encoder)
        end = time.perf_counter()
        best["observations ms"] = min(best["observations ms"], 1e3 * (middle - start))
        best["encoder ms"] = min(best["encoder ms"], 1e3 * (end - middle))
    return best


def query_times(call, repeat: int) -> dict:
    """Per stage ms of the fastest of `repeat` whole queries, the whole query's wall time, and its cap."""
    best, timings, cap = np.inf, {}, None
    for _ in range(repeat):
        start = time.perf_counter()
        result = call()
        seconds = time.perf_counter() - start
        if seconds < best:
            best, timings, cap = seconds, result.timings, result.cap_hit
    return {f"{stage} ms": 1e3 * value for stage, value in timings.items()} | {"localize ms": 1e3 * best,
                                                                                "cap": None if cap is None
                                                                               else str(cap)}


def table(rows: dict[str, list[dict]], keys: list[str]) -> None:
    labels = list(rows)
    print(f"  {'stage':<14}" + "".join(f"{label + ' median':>16}{'p90':>8}" for label in labels))
    for key in keys:
        cells = ""
        for label in labels:
            values = [row[key] for row in rows[label] if key in row]
            cells += f"{np.median(values):>16.2f}{np.percentile(values, 90):>8.2f}" if values else f"{'-':>16}{'-':>8}"
        print(f"  {key.removesuffix(' ms'):<14}{cells}")


def compare_scene(scene: str, workers: list[Worker], max_frames: int, repeat: int) -> None:
    counts = [worker.ask(kind="scene", scene=scene, max_frames=max_frames)["frames"] for worker in workers]
    for worker in workers:  # warm up: numba compiles a fresh tree's functions on first use
        worker.ask(kind="scene", scene=scene, max_frames=max_frames, frame=0, repeat=1, literal=False)
    rows: dict[str, list[dict]] = {worker.label: [] for worker in workers}
    for i in range(min(counts)):
        for worker in workers:
            rows[worker.label].append(worker.ask(kind="scene", scene=scene, max_frames=max_frames, frame=i,
                                                 repeat=repeat, literal=worker is workers[-1]))
    now = rows[workers[-1].label]
    observed = [row["observations"] for row in now]
    print(f"{scene}: {len(now)} frames, observations per frame median {np.median(observed):.0f}, at most "
          f"{max(observed)}; ms, fastest of {repeat} per frame")
    stages = [key for key in now[0] if key.endswith(" ms") and key not in ("localize ms", "literal ms")]
    table(rows, stages + ["localize ms"])
    for label, answers in rows.items():
        detections = sum(row["detections"] for row in answers)
        per_detection = [row["observations ms"] / row["detections"] for row in answers if row["detections"]]
        print(f"  observations per detection, {label}: median {np.median(per_detection):.3f} ms over frames, "
              f"{sum(row['observations ms'] for row in answers) / max(detections, 1):.3f} ms over all "
              f"{detections} detections")
    project, literal = np.median([row["localize ms"] for row in now]), np.median([row["literal ms"] for row in now])
    print(f"  whole localize (descriptors to confidence) {project:.2f} ms, literal reference {literal:.2f} ms: "
          f"{literal / project:.1f}x", flush=True)


def compare_clutter(counts: list[int], workers: list[Worker], frames: int, repeat: int) -> None:
    scene = clutter_scene(frames)
    print(f"clutter: the desk scene copied into rooms 20 m apart, SH only, {frames} queries per size, ms; index s: "
          f"index_map's first call on the map, numba initialised before it (its one-time process initialisation: "
          + ", ".join(f"{worker.label} {worker.ask(kind='numba')['numba start s']:.3f} s" for worker in workers) + ")")
    print(f"  {'landmarks':>9} {'tree':>8} {'index s':>8} {'median':>8} {'p90':>8} {'p90/med':>8} {'caps':>5} "
          f"{'peak MB':>8} {'literal':>8}")
    for count in counts:
        for worker in workers:  # warm up (the index is built, compiled functions loaded)
            worker.ask(kind="clutter", landmarks=count, scene=scene, query=0, repeat=1, literal=False)
        rows: dict[str, list[dict]] = {worker.label: [] for worker in workers}
        for q in range(frames):
            for worker in workers:
                rows[worker.label].append(worker.ask(kind="clutter", landmarks=count, scene=scene, query=q,
                                                     repeat=repeat, literal=worker is workers[-1]))
        for label, answers in rows.items():
            times = [row["localize ms"] for row in answers]
            literal = [row["literal ms"] for row in answers if "literal ms" in row]
            median, p90 = np.median(times), np.percentile(times, 90)
            print(f"  {answers[0]['landmarks']:>9} {label:>8} {answers[0]['index s']:>8.3f} {median:>8.2f} {p90:>8.2f} "
                  f"{p90 / median:>8.2f} {sum(row['cap'] is not None for row in answers):>5} "
                  f"{max(row['peak MB'] for row in answers):>8.0f} "
                  f"{np.median(literal) if literal else float('nan'):>8.1f}", flush=True)


def compare_recording(scene: str, workers: list[Worker], max_frames: int, directory: Path) -> None:
    print(f"recording of {scene} ({max_frames} frames): ms on the caller's thread per frame")
    for worker in workers:
        answer = worker.ask(kind="recording", scene=scene, max_frames=max_frames,
                            out=str(directory / f"{worker.label}.rrd"))
        calls = answer["log_frame ms"]
        print(f"  {worker.label:>8}: log_frame median {np.median(calls):.2f} ms, p90 {np.percentile(calls, 90):.2f}, "
              f"close {answer['close s']:.2f} s, recorder thread CPU {answer['thread CPU s']:.2f} s, "
              f"{answer['kB per frame']:.0f} kB per frame", flush=True)


def compare_whole_runs(scene: str, trees: dict[str, Path], runs: int, directory: Path) -> None:
    """Wall seconds of whole `clipclique-loc run` processes (start included), each tree in turn, after
    one warm-up run each (numba's cache); with and without the recording."""
    print(f"whole `clipclique-loc run {scene}` processes, seconds (median of {runs}, trees alternating, "
          "numba cache warm):")
    seconds: dict[tuple[str, bool], list[float]] = {}
    # CPU seconds, user + system: what a loaded machine leaves alone
    processor: dict[tuple[str, bool], list[float]] = {}
    for attempt in range(runs + 1):
        for label, tree in trees.items():
            for record in (True, False):
                # -P: `python -c` puts the working directory (this tree) ahead of PYTHONPATH; without it "before"
                # ran this tree's code too
                entry = ("from clipclique.localization.cli import main; main()"
                         if (tree / "clipclique" / "localization").is_dir()
                         else "from localization.cli import main; main()")  # a tree from before the move
                command = [sys.executable, "-P", "-c", entry, "run", scene,
                           "--out", str(directory / f"run-{label}")] + ([] if record else ["--no-rrd"])
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                start = time.perf_counter()
                subprocess.run(command, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(tree)), check=True,
                               capture_output=True)
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                if attempt:  # the first round warms the caches
                    seconds.setdefault((label, record), []).append(time.perf_counter() - start)
                    processor.setdefault((label, record), []).append(
                        after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    for (label, record), values in seconds.items():
        print(f"  {label:>8} {'with' if record else 'without'} the recording: {np.median(values):.1f} s "
              f"({', '.join(f'{v:.1f}' for v in values)}), CPU {np.median(processor[label, record]):.1f} s",
              flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="*", default=["demo_desk", "demo_apartment", "demo"])
    parser.add_argument("--rev", default=None, help="git revision timed beside the working tree "
                                                    "(default: the merge base with main; 'none': "
                                                    "the working tree alone)")
    parser.add_argument("--max-frames", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--clutter", type=int, nargs="*", default=[], metavar="LANDMARKS")
    parser.add_argument("--clutter-frames", type=int, default=20)
    parser.add_argument("--recording", type=int, default=0, metavar="FRAMES",
                        help="also time the recording of the first scene's first FRAMES frames")
    parser.add_argument("--whole-runs", type=int, default=0, metavar="N",
                        help="also time N whole `clipclique-loc run` processes of the first scene per tree")
    parser.add_argument("--cpu", type=int, default=None, metavar="CORE",
                        help="pin both workers to this core, so that before and now run on the same one (a VM's "
                             "cores can differ, and by the minute); default: where the system puts them")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        serve()
        return
    if args.cpu is not None and args.cpu not in os.sched_getaffinity(0):
        parser.error(f"--cpu {args.cpu}: not one of this process's cores {sorted(os.sched_getaffinity(0))}")
    numba_start_seconds()  # numba's cache of the trivial function the workers time, before they start
    rev = args.rev or subprocess.run(["git", "merge-base", "HEAD", "main"], cwd=ROOT, capture_output=True,
                                     text=True).stdout.strip() or "HEAD"
    with tempfile.TemporaryDirectory() as directory:
        workers = []
        if rev != "none":
            archive = subprocess.run(["git", "archive", rev], cwd=ROOT, capture_output=True)
            if archive.returncode:
                parser.exit(2, f"bench_speed: error: --rev {rev}: {archive.stderr.decode().strip()}\n")
            subprocess.run(["tar", "-x", "-C", directory], input=archive.stdout, check=True)
            workers.append(Worker(Path(directory), "before", args.cpu))
        workers.append(Worker(ROOT, "now", args.cpu))
        pinned = f"both workers on core {args.cpu}" if args.cpu is not None else "workers not pinned"
        print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} (a shared machine gives noisy "
              f"timings), {pinned}; before = {rev}, now = the working tree", flush=True)
        try:
            for scene in args.scenes:
                compare_scene(scene, workers, args.max_frames, args.repeat)
            if args.recording:
                compare_recording(args.scenes[0], workers, args.recording, Path(directory))
            if args.whole_runs:
                trees = {"now": ROOT} if rev == "none" else {"before": Path(directory), "now": ROOT}
                compare_whole_runs(args.scenes[0], trees, args.whole_runs, Path(directory))
            if args.clutter:
                compare_clutter(args.clutter, workers, args.clutter_frames, args.repeat)
        finally:
            for worker in workers:
                worker.close()
            print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
