"""`clipclique-bench`: localize many scenes with many configurations, in this process or on a Dask cluster.

This module parses the options, draws the progress and prints; the work is clipclique.benchmark.engine's.
Heavy modules (dask, open3d, torch) are imported inside the command so `--help` is instant.
"""

from __future__ import annotations

import shlex
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, Iterator, Optional

import typer

from clipclique.blas import one_blas_thread_by_default
from clipclique.exits import version_option
from clipclique.io.outputs import BENCH_DIR, CACHE_DIR
from clipclique.localization.inputs import (
    CameraInfoTopicOption,
    DepthScaleOption,
    DepthTopicOption,
    GroundtruthOption,
    GtFramesOption,
    LabelsOption,
    MapOption,
    MinScoreOption,
    OdometryDriftOption,
    OdometryOption,
    RgbTopicOption,
    RunInputs,
    SamePlaceOption,
    StrictDetectionsOption,
    WindowOption,
    WindowSpanOption,
    WindowStepOption,
)

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__.splitlines()[0],
                  context_settings={"help_option_names": ["-h", "--help"]})

TOOL = "clipclique-bench"
WHAT, INPUTS, ENGINE, OUTPUT = "What to run", "Inputs", "Where to run", "Output"


@app.command()
def main_command(
    scenes: Annotated[Optional[list[str]], typer.Argument(
        help="scene names (demo, demo_tum, scene0002_00, fr2, ...), folders or globs (quoted: "
             "'data/scannet/scans/scene*')",
        show_default=False)] = None,
    methods: Annotated[str,
                       typer.Option(help="comma-separated presets: clipclique, clipclique-paper, sh, xview, cliploc",
                                         rich_help_panel=WHAT)] = "clipclique",
    grid: Annotated[Optional[list[str]], typer.Option(
        help="KEY=V1,V2,...: one run per value (several --grid: every combination), e.g. inliers.d_comp=0.2,0.3",
        rich_help_panel=WHAT)] = None,
    plan: Annotated[Optional[Path], typer.Option(help="TOML plan file (scenes, methods, grid, stride, max_frames, "
                                                      "detector, encoder); instead of the above",
                                                 rich_help_panel=WHAT)] = None,
    stride: Annotated[int, typer.Option(min=1, help="use every N-th frame", rich_help_panel=INPUTS)] = 1,
    max_frames: Annotated[Optional[int], typer.Option(min=1, help="stop after N frames",
                                                      rich_help_panel=INPUTS)] = None,
    detector: Annotated[Optional[str], typer.Option(help="as clipclique-loc run --detector",
                                                    rich_help_panel=INPUTS)] = None,
    encoder: Annotated[Optional[str], typer.Option(help="as clipclique-loc run --encoder",
                                                   rich_help_panel=INPUTS)] = None,
    # --- the input options shared with clipclique-loc run (clipclique.localization.inputs, issue 38)
    map_path: MapOption = None,
    same_place: SamePlaceOption = False,
    min_score: MinScoreOption = None,
    labels: LabelsOption = None,
    strict_detections: StrictDetectionsOption = False,
    window: WindowOption = 1,
    window_step: WindowStepOption = None,
    window_span: WindowSpanOption = None,
    odometry: OdometryOption = None,
    odometry_drift: OdometryDriftOption = 0.0,
    rgb_topic: RgbTopicOption = None,
    depth_topic: DepthTopicOption = None,
    camera_info_topic: CameraInfoTopicOption = None,
    depth_scale: DepthScaleOption = None,
    groundtruth: GroundtruthOption = None,
    gt_frames: GtFramesOption = None,
    # --- end of the shared input options
    data_root: Annotated[Optional[Path], typer.Option(help="datasets folder \\[default: $CLIPCLIQUE_DATA or ./data]",
                                                      rich_help_panel=INPUTS)] = None,
    workers: Annotated[Optional[int], typer.Option(min=1,
                                                   help="a local Dask cluster of N worker processes (127.0.0.1 only)",
                                                   rich_help_panel=ENGINE)] = None,
    scheduler: Annotated[Optional[str], typer.Option(help="join a running Dask cluster, e.g. tcp://head:8786",
                                                     rich_help_panel=ENGINE)] = None,
    out: Annotated[Path, typer.Option(help="OUT/SCENE/RUN/ per run (as clipclique-loc run writes), and "
                                           "OUT/report.md, summary.json, success.png",
                                      rich_help_panel=OUTPUT)] = BENCH_DIR,
    cache: Annotated[Path, typer.Option(help="perception cache (observations and embeddings per frame)",
                                        rich_help_panel=OUTPUT)] = CACHE_DIR,
    record: Annotated[bool, typer.Option("--record", help="also write each run's Rerun recording",
                                         rich_help_panel=OUTPUT)] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only where the results are",
                                        rich_help_panel=OUTPUT)] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="also print the tables of every run",
                                          rich_help_panel=OUTPUT)] = False,
    version: Annotated[bool, typer.Option("--version", callback=version_option(TOOL), is_eager=True,
                                          help="print the version and exit")] = False,
) -> None:
    """Run scenes x methods x settings; resume where an earlier run of the same command stopped."""
    from rich.console import Console
    from rich.markup import escape

    from clipclique.benchmark import aggregate
    from clipclique.benchmark.engine import run_jobs
    from clipclique.benchmark.plan import Plan, PlanError, parse_grid, read_plan, runs
    from clipclique.exits import user_errors
    from clipclique.localization.tables import make_console, print_documents

    console = make_console()
    with user_errors(TOOL):
        inputs = RunInputs(map_path, same_place, min_score, labels, strict_detections, window, window_step, odometry,
                           odometry_drift, window_span, rgb_topic, depth_topic, camera_info_topic, depth_scale,
                           groundtruth, gt_frames)
        if plan is not None:
            if scenes or grid or methods != "clipclique" or inputs != RunInputs():
                raise PlanError(f"--plan {plan}: give the scenes, methods, grid and inputs in the plan file, not as "
                                "well on the command line")
            chosen = read_plan(plan)
        elif not scenes:
            raise PlanError("no scenes: name some (e.g. demo demo_tum) or pass --plan FILE.toml")
        else:
            chosen = Plan(scenes, [m.strip() for m in methods.split(",")], parse_grid(grid or []), stride, max_frames,
                          detector, encoder, inputs)
        if workers is not None and scheduler is not None:
            raise PlanError("--workers starts a local cluster, --scheduler joins one: pass one of them")
        settings = runs(chosen, out, data_root, record)
        with _client(workers, scheduler) as client, _Bar(Console(stderr=True), quiet) as bar:
            result = run_jobs(settings, cache, bar, client)
        aggregate.write(result, out, shlex.join([TOOL, *sys.argv[1:]]))
    if verbose and result.documents:
        print_documents(console, result.documents)
    if not quiet:
        console.print(f"{len(result.documents)} runs ({result.skipped} already finished), {len(result.failed)} failed, "
                      f"{result.tasks} tasks, {result.wall_s:.1f} s", highlight=False)
    console.print(f"report: {escape(str(out / 'report.md'))}, runs: {escape(str(out))}/SCENE/RUN/", highlight=False,
                  soft_wrap=True)
    if result.failed:
        raise typer.Exit(1)


@contextmanager
def _client(workers: int | None, scheduler: str | None) -> Iterator[Any]:
    """None (this process), a local cluster's client or a running cluster's."""
    if workers is None and scheduler is None:
        yield None
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        from clipclique.errors import ClipcliqueError

        raise ClipcliqueError("--workers and --scheduler need Dask: pip install 'clipclique[cluster]'") from None
    if scheduler is not None:
        with Client(scheduler) as client:
            yield client
        return
    # GPU=1: a perception task on CUDA asks for it (on a CPU-only machine no task does)
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, resources={"GPU": 1}) as cluster, Client(cluster) as client:
        yield client


class _Bar:
    """A progress bar over all tasks (done, running, failed, elapsed, remaining); a failed task is one line."""

    def __init__(self, console: Any, quiet: bool) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.console = console
        self.progress = Progress(TextColumn("tasks"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("running {task.fields[running]}, failed {task.fields[failed]}"),
                                 TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn(),
                                 console=console, transient=True, disable=quiet)
        self.task = self.progress.add_task("tasks", total=None, running=0, failed=0)

    def __enter__(self) -> _Bar:
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.__exit__(*exc)

    def start(self, total: int) -> None:
        self.progress.update(self.task, total=total)

    def update(self, done: int, running: int, failed: int) -> None:
        self.progress.update(self.task, completed=done, running=running, failed=failed)

    def failed(self, failure: Any) -> None:
        from rich.markup import escape

        self.console.print(f"{TOOL}: task failed: {escape(failure.task.label())}: {escape(failure.reason)}",
                           highlight=False, soft_wrap=True)


def main() -> None:
    one_blas_thread_by_default()  # as clipclique-loc (clipclique.blas)
    app()


if __name__ == "__main__":
    main()
