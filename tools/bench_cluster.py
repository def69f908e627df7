"""Wall time of clipclique-bench's engine in this process against a local cluster, in one run.

    .venv/bin/python tools/bench_cluster.py [--workers 2] [--max-frames N] [--out /tmp/bench-cluster]

The four generated scenes x the five presets, from an empty perception cache each time: in this
process, then on `--workers` local worker processes; the runs' results are compared frame by frame.
Then resume: an in-process benchmark interrupted halfway (Ctrl-C after half its tasks) and run
again, which does only the remaining tasks. Prints the machine's load average before and after
(a shared machine slows every figure).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path

from clipclique.blas import one_blas_thread_by_default  # noqa: E402

one_blas_thread_by_default()  # as clipclique-loc runs, before numpy loads (clipclique.blas)

from clipclique.benchmark.engine import ensure_map, run_jobs  # noqa: E402
from clipclique.benchmark.plan import Plan, runs  # noqa: E402
from clipclique.config import METHOD_PRESETS  # noqa: E402
from clipclique.localization.results import read_results  # noqa: E402
from clipclique.sim import DEMO_SCENES  # noqa: E402


class Quiet:
    """A tracker that says nothing, or interrupts after `stop_after` tasks."""

    def __init__(self, stop_after: int | None = None) -> None:
        self.stop_after = stop_after

    def start(self, total: int) -> None:
        pass

    def update(self, done: int, running: int, failed: int) -> None:
        if self.stop_after is not None and done >= self.stop_after:
            raise KeyboardInterrupt

    def failed(self, failure) -> None:
        print("failed:", failure.task.label(), failure.reason)


def decisions(out: Path) -> dict[str, list]:
    """Per run folder, every frame's results without its timings."""
    found = {}
    for path in sorted(out.glob("*/*/results.json")):
        frames = read_results(path)["frames"]
        found[str(path.parent.relative_to(out))] = [{k: v for k, v in f.items() if k != "timings_ms"} for f in frames]
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench-cluster"))
    args = parser.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    plan = Plan(list(DEMO_SCENES), list(METHOD_PRESETS), max_frames=args.max_frames)
    for scene in plan.scenes:
        ensure_map(scene, None)
    print(f"{len(plan.scenes)} scenes x {len(plan.methods)} presets, max frames {args.max_frames}; "
          f"load average before: {os.getloadavg()}, {os.cpu_count()} cores")
    timings = {}
    start = time.perf_counter()
    result = run_jobs(runs(plan, args.out / "in-process", None, False), args.out / "cache-in-process", Quiet())
    timings["in-process"] = time.perf_counter() - start
    print(f"in-process: {timings['in-process']:.1f} s, {result.tasks} tasks, {len(result.documents)} runs")

    from distributed import Client, LocalCluster, get_task_stream

    start = time.perf_counter()
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster) as client:
        with get_task_stream(client) as stream:
            result = run_jobs(runs(plan, args.out / "cluster", None, False), args.out / "cache-cluster", Quiet(),
                              client)
    timings["cluster"] = time.perf_counter() - start
    busy = sum(part["stop"] - part["start"] for task in stream.data for part in task["startstops"]
               if part["action"] == "compute")
    print(f"--workers {args.workers}: {timings['cluster']:.1f} s (cluster start included), {result.tasks} tasks; "
          f"speed-up {timings['in-process'] / timings['cluster']:.2f}x; the workers computed for {busy:.1f} s in all "
          f"({busy / timings['cluster']:.2f} workers busy on average)")
    same = decisions(args.out / "in-process") == decisions(args.out / "cluster")
    print(f"identical results: {same} ({len(decisions(args.out / 'cluster'))} runs)")

    resumed = runs(plan, args.out / "resume", None, False)
    total = result.tasks
    try:
        run_jobs(resumed, args.out / "cache-resume", Quiet(stop_after=total // 2))
    except KeyboardInterrupt:
        pass
    start = time.perf_counter()
    again = run_jobs(resumed, args.out / "cache-resume", Quiet())
    timings["resume"] = time.perf_counter() - start
    print(f"resume after an interrupt at {total // 2} of {total} tasks: {again.tasks} tasks, {again.skipped} runs "
          f"already finished, {timings['resume']:.1f} s; identical: "
          f"{decisions(args.out / 'in-process') == decisions(args.out / 'resume')}")
    print(f"load average after: {os.getloadavg()}")
    (args.out / "timings.json").write_text(json.dumps(timings))


if __name__ == "__main__":
    main()
