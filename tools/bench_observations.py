"""The observation stage (`extract_observations`) of the working tree beside a git revision's, on the same frames.

    .venv/bin/python tools/bench_observations.py [SCENE ...] [--rev d350f9d] [--max-frames 40] [--repeat 3]
                                                 [--clock wall|cpu]

The revision's `clipclique/perception/observations.py`, `geometry.py` and `encoders.py` are loaded from git as
modules of their own, so both versions run in one process on the same detections (the
sequence's own detector, run once per frame and not timed). Each frame is fitted `--repeat`
times by each version, alternating, and the fastest kept, which damps the noise of a shared
machine; `--clock cpu` times the thread's CPU time instead of the wall's, which a loaded
machine disturbs less (it still slows the caches). Printed per scene: median ms per frame (also
over the frames with 15 detections or more), ms per detection (total time over all detections),
and the largest difference between
the two versions' ellipsoids over every frame (kept detections, drop counts, crops and crop
contents must be equal).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

# one BLAS thread, as clipclique-loc runs (clipclique.blas), set here: the --rev worker imports another tree
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from clipclique.exits import user_errors  # noqa: E402
from clipclique.localization.run import RunSettings, prepare, selected_frames  # noqa: E402
from clipclique.perception.encoders import Crop  # noqa: E402
from clipclique.perception.observations import Extraction, extract_observations  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BEFORE = "d350f9d"  # the last commit before the compiled window pass (README, Observation stage)
CROWDED = 15  # detections: the frames of the target, 15 objects in 15 ms (issue 10)


def load_revision(rev: str, directory: Path) -> ModuleType:
    """`clipclique.perception.observations` as of `rev`, importing that revision's `clipclique.geometry` and
    `.encoders`."""
    def load(name: str) -> ModuleType:
        source = subprocess.run(["git", "show", f"{rev}:clipclique/{name}.py"], cwd=ROOT, capture_output=True,
                                text=True, check=True).stdout
        path = directory / f"{name}.py"  # a file, so numba can cache the revision's compiled functions
        path.write_text(source)
        spec = importlib.util.spec_from_file_location(f"revision_{name}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # dataclasses look their module up there
        spec.loader.exec_module(module)
        return module

    imported = ("geometry", "encoders")  # what the revision's observations module imports
    current = {name: sys.modules.get(f"clipclique.{name}") for name in imported}  # None: not a module here now
    for name in imported:
        sys.modules[f"clipclique.{name}"] = load(name)
    try:
        return load("observations")
    finally:
        for name in imported:
            if current[name] is None:
                del sys.modules[f"clipclique.{name}"]
            else:
                sys.modules[f"clipclique.{name}"] = current[name]


def difference(new: Extraction, old) -> float:
    """Largest absolute difference of the ellipsoids; raises when anything else differs."""
    theirs = crop_parts(old)
    same = (new.dropped == old.dropped
            and np.array_equal(new.observations.detection_index, old.observations.detection_index)
            and np.array_equal(new.observations.mask_areas, old.observations.mask_areas)
            and len(new.crops) == len(theirs)
            and all(crop.truncated == truncated and shares(crop) in (None, contents)
                    and np.array_equal(crop.pixels, pixels)
                    for crop, (pixels, truncated, contents) in zip(new.crops, theirs)))
    if not same:
        raise AssertionError("the two versions keep, drop, crop or count differently")
    if not len(new.observations):
        return 0.0
    ours, theirs = new.observations.ellipsoids, old.observations.ellipsoids
    return max(float(np.abs(a - b).max()) for a, b in ((ours.centers, theirs.centers), (ours.axes, theirs.axes),
                                                        (ours.rotations, theirs.rotations)))


def crop_parts(extraction) -> list[tuple[np.ndarray, bool, object]]:
    """(pixels, truncated, contents or None) per crop of a revision's extraction: `Crop` records, or
    before them (d350f9d and earlier) parallel lists."""
    if hasattr(extraction, "truncated"):
        return list(zip(extraction.crops, extraction.truncated, extraction.contents))
    return [(crop.pixels, crop.truncated, shares(crop)) for crop in extraction.crops]


def shares(crop: Crop) -> tuple[tuple[int, float], ...] | None:
    """(object id, share of the pixels) per id of a crop's instance image, as the revision's `contents`
    held them (None without an instance image)."""
    if crop.instances is None:
        return None
    ids, counts = np.unique(crop.instances, return_counts=True)
    return tuple(zip(ids.tolist(), (counts / counts.sum()).tolist()))


CLOCKS = {"wall": time.perf_counter, "cpu": time.thread_time}  # cpu: this thread's time, blind to other jobs


def fastest(function, frame, detections, repeat: int, clock=time.perf_counter) -> tuple[float, object]:
    best, result = np.inf, None
    for _ in range(repeat):
        start = clock()
        result = function(frame, detections)
        best = min(best, clock() - start)
    return best, result


def bench(scene: str, old: ModuleType, max_frames: int, repeat: int, clock=time.perf_counter) -> None:
    run = prepare(RunSettings(scene, max_frames=max_frames, record=False))
    times: dict[str, list[float]] = {"before": [], "now": []}
    detections_per_frame, worst = [], 0.0
    for i in selected_frames(run):
        frame = run.sequence[i]
        detections = run.detector.detect(frame)
        before, theirs = fastest(old.extract_observations, frame, detections, repeat, clock)
        now, ours = fastest(extract_observations, frame, detections, repeat, clock)
        times["before"].append(before)
        times["now"].append(now)
        detections_per_frame.append(len(detections))
        worst = max(worst, difference(ours, theirs))
    total, crowded = sum(detections_per_frame), np.array(detections_per_frame) >= CROWDED
    print(f"{scene}: {len(detections_per_frame)} frames, detections per frame {total / len(detections_per_frame):.1f} "
          f"on average, median {np.median(detections_per_frame):.0f}, at most {max(detections_per_frame)} "
          f"(detector {run.detector.name}); {crowded.sum()} frames with {CROWDED} or more")
    for label, seconds in times.items():
        busy = (f", {1e3 * np.median(np.array(seconds)[crowded]):6.2f} ms on those {crowded.sum()}"
                if crowded.any() else "")
        print(f"  {label:7s} {1e3 * np.median(seconds):6.2f} ms per frame (median{busy}), "
              f"{1e3 * sum(seconds) / max(total, 1):5.2f} ms per detection")
    print(f"  largest ellipsoid difference (centres, axes, rotations): {worst:.1e}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", default=["demo", "demo_apartment", "demo_desk"])
    parser.add_argument("--rev", default=BEFORE,
                        help=f"the git revision timed beside the working tree (default {BEFORE})")
    parser.add_argument("--max-frames", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="wall",
                        help="wall time, or the thread's CPU time (steadier on a loaded machine)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        try:
            old = load_revision(args.rev, Path(directory))
        except subprocess.CalledProcessError as error:
            parser.exit(2, f"bench_observations: error: --rev {args.rev}: {error.stderr.strip()}\n")
        print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} (a shared machine gives noisy timings); "
              f"before = {args.rev}, now = the working tree; {args.clock} time")
        with user_errors("bench_observations"):  # a missing map or sequence: one line
            for scene in args.scenes:
                bench(scene, old, args.max_frames, args.repeat, CLOCKS[args.clock])


if __name__ == "__main__":
    main()
