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
from clipclique.localization.inputs import (
    BAG,
    INPUTS,
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
    bag_options,
)

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__.splitlines()[0],
                  context_settings={"help_option_names": ["-h", "--help"]})

TOOL = "clipclique-loc"
ALGORITHM, OUTPUT = "Algorithm", "Output"


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
    sequence: Annotated[str, typer.Argument(help="demo, demo_tum, demo_apartment, demo_desk, scene0002_00, fr2, fr3, a "
                                                 "sequence folder, or a ROS bag (.bag, ROS 2 folder, .mcap, .db3)")],
    method: Annotated[str, typer.Option(help="clipclique | clipclique-paper | sh | xview | cliploc, or the name a "
                                             "table prints (CLIP-Clique, X-View, ...)",
                                        rich_help_panel=ALGORITHM)] = "clipclique",
    top_n: Annotated[Optional[int], typer.Option(help="poses kept per frame \\[default: 5]",
                                                 rich_help_panel=ALGORITHM)] = None,
    config: Annotated[Optional[Path], typer.Option(help="TOML file of parameters, or a run's config.json",
                                                   rich_help_panel=ALGORITHM)] = None,
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="override, e.g. inliers.d_comp=0.4",
                                                      rich_help_panel=ALGORITHM)] = None,
    min_confidence: Annotated[Optional[float], typer.Option(
        min=0.0, max=1.0, help="report a frame whose poses are all less confident as not localized "
                               "(confidence: the calibrated probability that a pose is within 1 m)",
        rich_help_panel=ALGORITHM)] = None,
    map_path: MapOption = None,
    data_root: Annotated[Optional[Path], typer.Option(help="datasets folder \\[default: $CLIPCLIQUE_DATA or ./data]",
                                                      rich_help_panel=INPUTS)] = None,
    detector: Annotated[Optional[str], typer.Option(
        help="gt | annotations | yolo | simulated | simulated-yolo | simulated-yolo-clutter | simulated-yolo-sparse | "
             "file:PATH (a detection file: OA-SLAM/VOOM/GOReloc "
             "JSON, or COCO results with ',images=LIST') \\[default: simulated on demo/demo_tum, simulated-yolo on "
             "demo_desk, simulated-yolo-clutter on demo_clutter, simulated-yolo-sparse on demo_sparse, gt on "
             "demo_apartment and ScanNet, annotations on TUM]", rich_help_panel=INPUTS)] = None,
    min_score: MinScoreOption = None,
    labels: LabelsOption = None,
    strict_detections: StrictDetectionsOption = False,
    yolo_weights: Annotated[str, typer.Option(help="YOLO-seg checkpoint for --detector yolo",
                                              rich_help_panel=INPUTS)] = "yolov8x-seg.pt",
    encoder: Annotated[Optional[str], typer.Option(
        help="auto | simulated | none | open_clip:MODEL/PRETRAINED | checkpoint file "
             "\\[default: the encoder of the map's text embeddings (simulated on the demo) if available, else none: "
             "SH only]",
        rich_help_panel=INPUTS)] = None,
    stride: Annotated[int, typer.Option(min=1, help="use every N-th frame", rich_help_panel=INPUTS)] = 1,
    max_frames: Annotated[Optional[int], typer.Option(min=1, help="stop after N frames",
                                                      rich_help_panel=INPUTS)] = None,
    same_place: SamePlaceOption = False,
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
        from clipclique.exits import user_errors
        from clipclique.localization.firstrun import compile_note
        from clipclique.localization.run import RunSettings, run_and_save
        from clipclique.localization.tables import make_console, print_documents, print_frames

        if not no_rrd:
            import clipclique.viz  # noqa: F401  (Rerun: imported here to be kept with the rest)
    overrides = list(set_ or []) + ([f"top_n={top_n}"] if top_n is not None else [])
    overrides += [f"min_confidence={min_confidence}"] if min_confidence is not None else []
    with user_errors(TOOL):
        method = method_key(method)
    with user_errors(TOOL):
        inputs = RunInputs(map_path, same_place, min_score, labels, strict_detections, window, window_step, odometry,
                           odometry_drift, window_span, rgb_topic, depth_topic, camera_info_topic, depth_scale,
                           groundtruth, gt_frames)
    settings = RunSettings(sequence, method, config, overrides, data_root=data_root, detector=detector,
                           encoder=encoder, yolo_weights=yolo_weights, stride=stride, max_frames=max_frames, out=out,
                           record=not no_rrd, **inputs.settings())
    console = make_console()
    with user_errors(TOOL), Progress(console=Console(stderr=True), transient=True, disable=quiet) as progress:
        title = escape(f"{sequence} / {method}")
        task = progress.add_task(f"{title} {compile_note()}".rstrip(), total=None)
        document = run_and_save(settings, lambda reached: progress.update(
            task, completed=reached.done, total=reached.total, description=f"{title} {reached.describe()}".rstrip()))
    if verbose:
        print_frames(console, document)
    if not quiet:
        print_documents(console, [document])
    if min_confidence:
        summary = document["summary"]
        console.print(f"not localized (no pose with confidence >= {min_confidence:g}): "
                      f"{int(summary['not_confident'])} of {int(summary['frames'])} frames")
    folder = settings.out_dir(document["run"]["sequence"])
    console.print(f"results: {escape(str(folder))}/ (results.json, frames.csv, poses.tum, groundtruth.tum, "
                  "config.json)", highlight=False, soft_wrap=True)
    recording = document["run"]["recording"]
    if recording is not None and recording["matches"]:
        earlier = "" if settings.record else ", an earlier run's with the same results"
        hint = rerun_hint(folder / recording["file"])
        console.print(escape(f"recording: {folder / recording['file']} ({hint}{earlier})"), highlight=False,
                      soft_wrap=True)
    elif recording is not None and quiet:  # the notes above say it; under -q, this does (every time)
        print(f"clipclique-loc: warning: {folder / recording['file']} is an earlier run's and does not show these "
              "results (run without --no-rrd to replace it)", file=sys.stderr)


@app.command()
def inspect(path: Annotated[Path, typer.Argument(help="a ROS bag: .bag, a ROS 2 bag folder, .mcap or .db3")],
            rgb_topic: Annotated[Optional[str], typer.Option(help="colour topic to check", rich_help_panel=BAG)] = None,
            depth_topic: Annotated[Optional[str], typer.Option(help="depth topic to check",
                                                               rich_help_panel=BAG)] = None,
            camera_info_topic: Annotated[Optional[str], typer.Option(help="CameraInfo topic to check",
                                                                     rich_help_panel=BAG)] = None) -> None:
    """A bag's topics (type, count, rate, encoding) and the colour, depth and CameraInfo topics a run would read."""
    from clipclique.exits import user_errors
    from clipclique.localization.tables import make_console, print_survey

    with user_errors(TOOL):
        from clipclique.datasets.rosbag import BagOptions, BagReader, require_bag, survey

        found = survey(BagReader(require_bag(path)), BagOptions(rgb_topic, depth_topic, camera_info_topic))
    print_survey(make_console(), found)
    if found.problem:
        raise typer.Exit(1)


@app.command()
def convert(
    path: Annotated[Path, typer.Argument(help="a ROS bag: .bag, a ROS 2 bag folder, .mcap or .db3")],
    to_tum: Annotated[Path, typer.Option("--to-tum", help="the TUM RGB-D folder to write (new, or empty)",
                                         show_default=False, rich_help_panel=OUTPUT)],
    rgb_topic: RgbTopicOption = None,
    depth_topic: DepthTopicOption = None,
    camera_info_topic: CameraInfoTopicOption = None,
    depth_scale: DepthScaleOption = None,
    groundtruth: GroundtruthOption = None,
    gt_frames: GtFramesOption = None,
    stride: Annotated[int, typer.Option(min=1, help="write every N-th frame", rich_help_panel=INPUTS)] = 1,
    max_frames: Annotated[Optional[int], typer.Option(min=1, help="stop after N frames",
                                                      rich_help_panel=INPUTS)] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only where the folder is",
                                        rich_help_panel=OUTPUT)] = False,
) -> None:
    """A bag as a TUM RGB-D folder (rgb/, depth/, rgb.txt, depth.txt, intrinsics.txt, groundtruth.txt) for any tool."""
    from rich.console import Console
    from rich.markup import escape
    from rich.progress import Progress

    from clipclique.exits import user_errors
    from clipclique.localization.tables import make_console

    console = make_console()
    options = bag_options(rgb_topic, depth_topic, camera_info_topic, depth_scale, groundtruth, gt_frames)
    with user_errors(TOOL), Progress(console=Console(stderr=True), transient=True, disable=quiet) as progress:
        from clipclique.datasets.rosbag import BagSequence, require_bag
        from clipclique.datasets.totum import check_target, write_tum_folder

        check_target(to_tum)  # before the bag's pass over its messages
        task = progress.add_task(escape(f"{path} -> {to_tum}"), total=None)
        sequence = BagSequence(require_bag(path), options)
        summary = write_tum_folder(sequence, to_tum, range(0, len(sequence), stride)[:max_frames],
                                   lambda done, total: progress.update(task, completed=done, total=total))
    for note in [] if quiet else [*sequence.notes(), sequence.missing_poses()]:
        if note:
            console.print(f"note: {escape(note)}", highlight=False, soft_wrap=True)
    console.print(escape(f"wrote {summary.frames} frames ({summary.poses} with ground truth) to {summary.out}/ "
                         f"({', '.join(summary.files)})"), highlight=False, soft_wrap=True)


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
    third: Annotated[Optional[Path], typer.Argument(
        metavar="[MAP_C]", help="a third map: align A into B, B into C, C into A and check that the cycle closes",
        show_default=False)] = None,
    method: Annotated[str, typer.Option(help="clipclique | clipclique-paper | sh | xview | cliploc (whose descriptors "
                                             "and matching align the maps)", rich_help_panel=ALGORITHM)] = "clipclique",
    top_n: Annotated[Optional[int], typer.Option(help="transforms kept \\[default: 5]",
                                                 rich_help_panel=ALGORITHM)] = None,
    config: Annotated[Optional[Path], typer.Option(help="TOML file of parameters", rich_help_panel=ALGORITHM)] = None,
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="override, e.g. inliers.d_comp=0.4",
                                                      rich_help_panel=ALGORITHM)] = None,
    out: Annotated[Optional[Path], typer.Option(help="\\[default: outputs/align/A_into_B]",
                                                rich_help_panel=OUTPUT)] = None,
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
    console = make_console()
    if third is not None:
        _align_cycle([query_map, map_path, third], method, config, overrides, out, not no_rrd, console)
        return
    with user_errors(TOOL):
        settings = AlignSettings(query_map, map_path, method_key(method), config, overrides, out, record=not no_rrd)
        document = align_and_save(settings)
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
        hint = escape(rerun_hint(settings.out_dir() / "recording.rrd"))
        console.print(f"recording: {out_dir}/recording.rrd ({hint})", highlight=False, soft_wrap=True)


def _align_cycle(maps: list[Path], method: str, config: Optional[Path], overrides: list[str], out: Optional[Path],
                 record: bool, console: object) -> None:
    """`align A B C`: each link written as `align` writes it (under OUT/ when given), then the cycle's closure."""
    from rich.markup import escape

    from clipclique.config import method_key
    from clipclique.exits import user_errors
    from clipclique.io.mapfile import load_map
    from clipclique.localization.align import AlignSettings, align_and_save
    from clipclique.localization.cycle import cycle

    documents = []
    with user_errors(TOOL):
        for query, target in zip(maps, maps[1:] + maps[:1]):
            settings = AlignSettings(query, target, method_key(method), config, overrides, None, record=record)
            settings.out = None if out is None else out / settings.out_dir().name
            documents.append(align_and_save(settings))
            best = documents[-1]["candidates"][:1]
            found = (f"confidence {best[0]['confidence']:.2f}, {len(best[0]['correspondences'])} correspondences"
                     if best else f"no alignment: {documents[-1]['failure']}")
            console.print(escape(f"{query} into {target}: {found}; results: {settings.out_dir()}/"), highlight=False,
                          soft_wrap=True)
        closure = cycle(documents, load_map(maps[0]).ellipsoids.centers)
    console.print(escape(closure.line() if closure else "cycle not checked: a link found no transform"),
                  highlight=False, soft_wrap=True)


def main() -> None:
    one_blas_thread_by_default()  # numpy is not imported yet, so this takes effect (clipclique.blas)
    try:
        app()
    finally:  # the process ends here: its heap is left to the OS, not collected object by object (~0.5 s after a run)
        gc.freeze()


if __name__ == "__main__":
    main()
