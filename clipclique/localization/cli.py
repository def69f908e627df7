"""`clipclique-loc`: localize every frame of a sequence against its map and score it.

This module parses the options and prints; the run itself is clipclique.localization.run.run_and_save.

Heavy modules (open3d, torch, rerun) are imported inside the commands so `--help` is instant.
"""

from __future__ import annotations

import gc
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Optional

import typer

from clipclique.blas import one_blas_thread_by_default
from clipclique.exits import version_option

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__.splitlines()[0],
                  context_settings={"help_option_names": ["-h", "--help"]})

TOOL = "clipclique-loc"
ALGORITHM, INPUTS, WINDOW, OUTPUT = "Algorithm", "Inputs", "Window of frames", "Output"


@app.callback()
def _tool(version: Annotated[bool, typer.Option("--version", callback=version_option(TOOL), is_eager=True,
                                                help="print the version and exit")] = False) -> None:
    """clipclique-loc: localize RGB-D frames against a landmark map (CLIP-Clique and its baselines)."""


@contextmanager
def imports_kept() -> Iterator[None]:
    """Imports made without garbage collection and then frozen (`gc.freeze`): what they make (numba's and Rerun's
    types, ...) is never garbage, yet every full collection of a run walked it again (two during the imports alone)."""
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()


@app.command()
def run(
    sequence: Annotated[str, typer.Argument(help="demo, demo_tum, demo_apartment, demo_desk, scene0002_00, fr2, fr3, or a sequence folder")],
    method: Annotated[str, typer.Option(help="clipclique | clipclique-paper | sh | xview | cliploc, or the name a "
                                             "table prints (CLIP-Clique, X-View, ...)",
                                        rich_help_panel=ALGORITHM)] = "clipclique",
    top_n: Annotated[Optional[int], typer.Option(help="poses kept per frame \\[default: 5]", rich_help_panel=ALGORITHM)] = None,
    config: Annotated[Optional[Path], typer.Option(help="TOML file of parameters, or a run's config.json", rich_help_panel=ALGORITHM)] = None,
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="override, e.g. inliers.d_comp=0.4",
                                                      rich_help_panel=ALGORITHM)] = None,
    min_confidence: Annotated[Optional[float], typer.Option(
        min=0.0, max=1.0, help="report a frame whose poses are all less confident as not localized "
                               "(confidence: the calibrated probability that a pose is within 1 m)",
        rich_help_panel=ALGORITHM)] = None,
    map_path: Annotated[Optional[Path], typer.Option("--map", help="map file \\[default: outputs/maps/SEQUENCE.map.npz]",
                                                     rich_help_panel=INPUTS)] = None,
    data_root: Annotated[Optional[Path], typer.Option(help="datasets folder \\[default: $CLIPCLIQUE_DATA or ./data]",
                                                      rich_help_panel=INPUTS)] = None,
    detector: Annotated[Optional[str], typer.Option(
        help="gt | annotations | yolo | simulated | simulated-yolo | simulated-yolo-clutter | simulated-yolo-sparse | file:PATH (a detection file: OA-SLAM/VOOM/GOReloc "
             "JSON, or COCO results with ',images=LIST') \\[default: simulated on demo/demo_tum, simulated-yolo on "
             "demo_desk, simulated-yolo-clutter on demo_clutter, simulated-yolo-sparse on demo_sparse, gt on demo_apartment and ScanNet, annotations on TUM]", rich_help_panel=INPUTS)] = None,
    min_score: Annotated[Optional[float], typer.Option(
        min=0.0, max=1.0, help="drop detections scoring lower (file: and yolo detectors)", rich_help_panel=INPUTS)] = None,
    yolo_weights: Annotated[str, typer.Option(help="YOLO-seg checkpoint for --detector yolo",
                                              rich_help_panel=INPUTS)] = "yolov8x-seg.pt",
    encoder: Annotated[Optional[str], typer.Option(
        help="auto | simulated | none | open_clip:MODEL/PRETRAINED | checkpoint file "
             "\\[default: the encoder of the map's text embeddings (simulated on the demo) if available, else none: "
             "SH only]",
        rich_help_panel=INPUTS)] = None,
    stride: Annotated[int, typer.Option(min=1, help="use every N-th frame", rich_help_panel=INPUTS)] = 1,
    max_frames: Annotated[Optional[int], typer.Option(min=1, help="stop after N frames", rich_help_panel=INPUTS)] = None,
    same_place: Annotated[bool, typer.Option(
        "--same-place", help="the map is of another recording of this place: localize against it (poses in the map's "
                             "frame; ground truth scored only if it shares that frame)", rich_help_panel=INPUTS)] = False,
    window: Annotated[int, typer.Option(min=1, help="localize each frame with the K - 1 frames before it, fused by "
                                               "odometry", metavar="K", rich_help_panel=WINDOW)] = 1,
    window_step: Annotated[Optional[int], typer.Option(min=1, help="the window takes every S-th frame back from the "
                                                       "newest \\[default: 1]", metavar="S",
                                                       rich_help_panel=WINDOW)] = None,
    # --- window span (issue 37): K frames spread over SECONDS instead of every S-th ---
    window_span: Annotated[Optional[float], typer.Option(
        help="the window's K frames spread over this many seconds back from the newest (not with --window-step)",
        metavar="SECONDS", rich_help_panel=WINDOW)] = None,
    # --- end window span ---
    odometry: Annotated[Optional[str], typer.Option(
        help="FILE.tum (a metric VO/SLAM trajectory, matched by timestamp; not scale-free monocular) or groundtruth "
             "(with --odometry-drift, simulated)", rich_help_panel=WINDOW)] = None,
    odometry_drift: Annotated[float, typer.Option(min=0.0, max=100.0, help="simulated drift of --odometry groundtruth, "
                                                  "percent of the distance travelled", metavar="PCT",
                                                  rich_help_panel=WINDOW)] = 0.0,
    out: Annotated[Optional[Path], typer.Option(
        help="\\[default: outputs/loc/SEQUENCE/RUN, RUN = the method and the settings given, e.g. "
             "clipclique+inliers.d_comp=0.4]", rich_help_panel=OUTPUT)] = None,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="skip the Rerun recording", rich_help_panel=OUTPUT)] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only where the results are",
                                        rich_help_panel=OUTPUT)] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="also print one line per frame",
                                          rich_help_panel=OUTPUT)] = False,
) -> None:
    """Localize each frame; print the paper's table; write results, TUM poses and a recording to the run's folder."""
    with imports_kept():
        from rich.console import Console
        from rich.markup import escape
        from rich.progress import Progress

        from clipclique.commands import rerun_hint
        from clipclique.config import method_key
        from clipclique.errors import ClipcliqueError
        from clipclique.exits import user_errors
        from clipclique.localization.run import RunSettings, run_and_save
        from clipclique.localization.tables import make_console, print_documents, print_frames

        if not no_rrd:
            import clipclique.viz  # noqa: F401  (Rerun: imported here to be kept with the rest)
    overrides = list(set_ or []) + ([f"top_n={top_n}"] if top_n is not None else [])
    overrides += [f"min_confidence={min_confidence}"] if min_confidence is not None else []
    with user_errors(TOOL):
        method = method_key(method)
    settings = RunSettings(sequence, method, config, overrides, map_path, data_root,
                           detector, encoder, yolo_weights, stride, max_frames, out,
                           record=not no_rrd, same_place=same_place, min_score=min_score or 0.0, window=window,
                           window_step=window_step or 1, odometry=odometry, odometry_drift=odometry_drift,
                           window_span=window_span)
    if window_span is not None and window_step is not None:  # window span (issue 37): one or the other
        with user_errors(TOOL):
            raise ClipcliqueError(f"--window-span {window_span:g} and --window-step {window_step} are mutually "
                                  "exclusive: give the span (seconds) or the step (frames)")
    console = make_console()
    with user_errors(TOOL), Progress(console=Console(stderr=True), transient=True, disable=quiet) as progress:
        task = progress.add_task(escape(f"{sequence} / {method}"), total=None)
        document = run_and_save(settings, lambda done, total: progress.update(task, completed=done, total=total))
    if verbose:
        print_frames(console, document)
    if not quiet:
        print_documents(console, [document])
    if min_confidence:
        summary = document["summary"]
        console.print(f"not localized (no pose with confidence >= {min_confidence:g}): "
                      f"{int(summary['not_confident'])} of {int(summary['frames'])} frames")
    folder = settings.out_dir(document["run"]["sequence"])
    console.print(f"results: {escape(str(folder))}/ (results.json, frames.csv, poses.tum, groundtruth.tum, config.json)",
                  highlight=False, soft_wrap=True)
    recording = document["run"]["recording"]
    if recording is not None and recording["matches"]:
        earlier = "" if settings.record else ", an earlier run's with the same results"
        console.print(escape(f"recording: {folder / recording['file']} ({rerun_hint(folder / recording['file'])}{earlier})"),
                      highlight=False, soft_wrap=True)
    elif recording is not None and quiet:  # the notes above say it; under -q, this does (every time)
        print(f"clipclique-loc: warning: {folder / recording['file']} is an earlier run's and does not show these "
              "results (run without --no-rrd to replace it)", file=sys.stderr)


@app.command()
def compare(results: Annotated[list[Path], typer.Argument(
        help="results.json files, run folders, or folders of run folders (outputs/loc/demo)")]) -> None:
    """One table of several runs (e.g. outputs/loc/demo/*); each names the settings that set it apart."""
    from clipclique.exits import user_errors
    from clipclique.localization.results import read_results, results_files
    from clipclique.localization.tables import make_console, print_documents

    with user_errors(TOOL):
        documents = [read_results(path) for given in results for path in results_files(given)]
    print_documents(make_console(), documents)


@app.command()
def align(
    query_map: Annotated[Path, typer.Argument(metavar="MAP_A", help="the map to align (the query map)")],
    map_path: Annotated[Path, typer.Argument(metavar="MAP_B", help="the map to align it into")],
    method: Annotated[str, typer.Option(help="clipclique | clipclique-paper | sh | xview | cliploc (whose descriptors "
                                             "and matching align the maps)", rich_help_panel=ALGORITHM)] = "clipclique",
    top_n: Annotated[Optional[int], typer.Option(help="transforms kept \\[default: 5]", rich_help_panel=ALGORITHM)] = None,
    config: Annotated[Optional[Path], typer.Option(help="TOML file of parameters", rich_help_panel=ALGORITHM)] = None,
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="override, e.g. inliers.d_comp=0.4",
                                                      rich_help_panel=ALGORITHM)] = None,
    out: Annotated[Optional[Path], typer.Option(help="\\[default: outputs/align/A_into_B]", rich_help_panel=OUTPUT)] = None,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="skip the Rerun recording", rich_help_panel=OUTPUT)] = False,
) -> None:
    """The transform taking MAP_A's coordinates into MAP_B's: JSON, a g2o edge and a recording of both maps."""
    from rich.markup import escape

    from clipclique.commands import rerun_hint
    from clipclique.config import method_key
    from clipclique.exits import user_errors
    from clipclique.localization.align import AlignSettings, align_and_save
    from clipclique.localization.tables import make_console

    overrides = list(set_ or []) + ([f"top_n={top_n}"] if top_n is not None else [])
    with user_errors(TOOL):
        settings = AlignSettings(query_map, map_path, method_key(method), config, overrides, out, record=not no_rrd)
        document = align_and_save(settings)
    console = make_console()
    for note in document["notes"]:
        console.print(f"note: {escape(note)}", highlight=False, soft_wrap=True)
    if not document["candidates"]:
        console.print(f"no alignment: {escape(str(document['failure']))}", highlight=False)
    for candidate in document["candidates"]:
        console.print(f"{candidate['rank']}: confidence {candidate['confidence']:.2f}, "
                      f"{len(candidate['correspondences'])} correspondences, rms {candidate['rms_m']:.3f} m",
                      highlight=False)
    if document["ambiguous"]:
        console.print(f"AMBIGUOUS: candidates {document['competitors']} score alike; the map repeats what the "
                      "query map holds", highlight=False)
    out_dir = escape(str(settings.out_dir()))
    console.print(f"results: {out_dir}/ (alignment.json, alignment.g2o)", highlight=False, soft_wrap=True)
    if settings.record:
        console.print(f"recording: {out_dir}/recording.rrd ({escape(rerun_hint(settings.out_dir() / 'recording.rrd'))})",
                      highlight=False, soft_wrap=True)


def main() -> None:
    one_blas_thread_by_default()  # numpy is not imported yet, so this takes effect (clipclique.blas)
    try:
        app()
    finally:  # the process ends here: its heap is left to the OS, not collected object by object (~0.5 s after a run)
        gc.freeze()


if __name__ == "__main__":
    main()
