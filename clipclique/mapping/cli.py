"""clipclique-map: build an object landmark map (ellipsoids + descriptions + CLIP text embeddings) of a scene.

This module parses the options and prints; the build itself is clipclique.mapping.run.run_build. Heavy modules
(open3d, torch, rerun) are imported inside the command, so `--help` is instant.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from clipclique.blas import one_blas_thread_by_default
from clipclique.exits import version_option

app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode="rich",
                  context_settings={"help_option_names": ["-h", "--help"]})
TOOL = "clipclique-map"

DATA_PANEL = "Data"
OUTPUT_PANEL = "Output"
ALIGN_PANEL = "Alignment to ground truth"


@app.callback()
def _tool(version: Annotated[bool, typer.Option("--version", callback=version_option(TOOL), is_eager=True,
                                                help="print the version and exit")] = False) -> None:
    """clipclique-map: build object landmark maps of ScanNet scenes, TUM RGB-D sequences and the demo."""


@app.command()
def build(
    scene: Annotated[str,
                     typer.Argument(help="scene0002_00, fr2, fr3, demo, demo_tum, demo_apartment, "
                                         "demo_desk, or a scene folder", show_default=False)],
    data_root: Annotated[
        Path | None,
        typer.Option("--data-root",
                     help="folder holding scannet/scans/, tum/, demo/ \\[default: $CLIPCLIQUE_DATA or ./data]",
                     rich_help_panel=DATA_PANEL),
    ] = None,
    out: Annotated[
        Path | None, typer.Option("--out", help="map file \\[default: outputs/maps/<SCENE>.map.npz]",
                                  rich_help_panel=OUTPUT_PANEL)
    ] = None,
    encoder: Annotated[
        str | None,
        typer.Option(
            "--encoder",
            help="text encoder: auto | simulated | none | open_clip:MODEL/TAG | checkpoint file "
            "\\[default: simulated for the demo scenes, auto elsewhere]",
            rich_help_panel=DATA_PANEL,
        ),
    ] = None,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="do not write the .rrd recording",
                                         rich_help_panel=OUTPUT_PANEL)] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only where the map is",
                                        rich_help_panel=OUTPUT_PANEL)] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="also print every landmark",
                                          rich_help_panel=OUTPUT_PANEL)] = False,
) -> None:
    """Build the landmark map of SCENE: one ellipsoid per object (walls, floors, ceilings left out)."""
    from rich.markup import escape
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from clipclique.exits import user_errors
    from clipclique.mapping.run import run_build
    from clipclique.mapping.tables import bar_on_first_call, make_console, print_build

    console = make_console()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    verbosity = verbose - quiet
    with user_errors(TOOL), Progress(*columns, console=console, transient=True, disable=verbosity < 0) as progress:
        built = run_build(scene, data_root, out, encoder, not no_rrd,
                          bars=lambda description: bar_on_first_call(progress, description),
                          say=lambda line: verbosity >= 0 and progress.console.print(escape(line), highlight=False))
    print_build(console, built, verbosity)


@app.command("import")
def import_map(
    path: Annotated[Path,
                    typer.Argument(help="map_objects_*.txt, an Osmap map_*.yaml, an MSG-Loc or clipclique JSON map",
                                   show_default=False)],
    format: Annotated[str | None, typer.Option("--format",
                                               help="oaslam-txt | osmap | msgloc | json "
                                                    "\\[default: from the file name]",
                                               rich_help_panel=DATA_PANEL)] = None,
    objects: Annotated[Path | None, typer.Option("--objects",
                                                 help="objects.csv (id,class,description): classes and "
                                                      "descriptions by object id", rich_help_panel=DATA_PANEL)] = None,
    labels: Annotated[str | None, typer.Option("--labels",
                                               help="coco | lvis | FILE (one class name per line, the 0-based line the "
                                                    "id): the label set of the map's category ids \\[default: coco]",
                                               rich_help_panel=DATA_PANEL)] = None,
    align_to: Annotated[str | None, typer.Option("--align-to",
                                                 help="fit the keyframe trajectory to this TUM sequence's "
                                                      "groundtruth.txt", rich_help_panel=ALIGN_PANEL)] = None,
    trajectory: Annotated[Path | None, typer.Option("--trajectory",
                                                    help="keyframe trajectory, TUM text \\[default: the one saved "
                                                         "beside the map]", rich_help_panel=ALIGN_PANEL)] = None,
    groundtruth: Annotated[Path | None, typer.Option("--groundtruth",
                                                     help="ground truth, TUM text (instead of --align-to)",
                                                     rich_help_panel=ALIGN_PANEL)] = None,
    scale: Annotated[bool, typer.Option("--scale", help="fit a scale too (monocular maps)",
                                        rich_help_panel=ALIGN_PANEL)] = False,
    min_keyframes: Annotated[int, typer.Option("--min-keyframes", min=3,
                                               help="refuse a fit over fewer matched keyframes",
                                               rich_help_panel=ALIGN_PANEL)] = 10,
    max_rmse: Annotated[float, typer.Option("--max-rmse", min=0.0, help="refuse a fit with a larger RMSE (metres)",
                                            rich_help_panel=ALIGN_PANEL)] = 0.05,
    data_root: Annotated[Path | None, typer.Option("--data-root",
                                                   help="folder holding tum/ \\[default: $CLIPCLIQUE_DATA or ./data]",
                                                   rich_help_panel=DATA_PANEL)] = None,
    out: Annotated[Path | None, typer.Option("--out", help="map file \\[default: outputs/maps/<file name>.map.npz]",
                                             rich_help_panel=OUTPUT_PANEL)] = None,
    encoder: Annotated[str, typer.Option("--encoder",
                                         help="text encoder: auto | simulated | none | open_clip:MODEL/TAG | "
                                              "checkpoint file", rich_help_panel=DATA_PANEL)] = "auto",
    force: Annotated[bool, typer.Option("--force",
                                        help="replace a map at --out that came from another source (an import of the "
                                             "same file replaces its own)", rich_help_panel=OUTPUT_PANEL)] = False,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="do not write the .rrd recording",
                                         rich_help_panel=OUTPUT_PANEL)] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only where the map is",
                                        rich_help_panel=OUTPUT_PANEL)] = False,
) -> None:
    """Import an object map of OA-SLAM, VOOM, GOReloc or MSG-Loc (or a clipclique JSON landmark list), optionally
    aligned to a sequence's ground truth: the same map file and .rrd as build."""
    from clipclique.exits import user_errors
    from clipclique.interop.align import AlignmentLimits
    from clipclique.interop.commands import AlignmentRequest
    from clipclique.interop.errors import InteropError
    from clipclique.interop.maps import MapFormat
    from clipclique.mapping.run import run_import
    from clipclique.mapping.tables import make_console, print_import

    console = make_console()
    with user_errors(TOOL):
        if format is not None and format not in set(MapFormat):
            raise InteropError(f"--format {format!r}: choose {', '.join(MapFormat)}")
        request = AlignmentRequest(trajectory=trajectory, with_scale=scale,
                                   limits=AlignmentLimits(min_keyframes, max_rmse))
        imported = run_import(path, MapFormat(format) if format else None, objects, align_to, groundtruth, request,
                              data_root, out, encoder, not no_rrd, labels, force)
    print_import(console, imported, quiet)


@app.command()
def export(
    map_path: Annotated[Path, typer.Argument(metavar="MAP", help="a clipclique map file (.map.npz)",
                                             show_default=False)],
    format: Annotated[str, typer.Option("--format", help="oaslam-txt | json", show_default=False)],
    out: Annotated[Path | None, typer.Option("--out",
                                             help="\\[default: beside the map: map_objects_<name>.txt or "
                                                  "<name>.landmarks.json]", rich_help_panel=OUTPUT_PANEL)] = None,
) -> None:
    """Write a map as an OA-SLAM text map or a clipclique JSON landmark list (what import reads back)."""
    from clipclique.exits import user_errors
    from clipclique.interop.commands import ExportFormat
    from clipclique.interop.errors import InteropError
    from clipclique.mapping.run import run_export
    from clipclique.mapping.tables import make_console, print_export

    with user_errors(TOOL):
        if format not in set(ExportFormat):
            raise InteropError(f"--format {format!r}: choose {' or '.join(ExportFormat)}")
        exported = run_export(map_path, ExportFormat(format), out)
    print_export(make_console(), exported)


@app.command()
def annotate(
    sequence: Annotated[str,
                        typer.Argument(help="a TUM-format sequence: rgbd_dataset_... under the "
                                            "data root, or its folder",
                                            show_default=False)],
    masks: Annotated[Path | None, typer.Option("--masks",
                                               help="folder of instance-id PNGs, each named after its colour "
                                               "image (file stem or timestamp); 0 = no object",
                                               show_default=False)] = None,
    coco: Annotated[Path | None, typer.Option("--coco",
                                              help="a COCO annotation file of instance masks (RLE or polygons, "
                                              "each with its object's track_id / instance_id / object_id), instead of "
                                              "--masks", show_default=False)] = None,
    objects: Annotated[Path | None, typer.Option("--objects", help="CSV table 'id,class,description' of the object ids "
                                                 "(with --coco: optional, else the categories give the classes)",
                                                 show_default=False)] = None,
    data_root: Annotated[
        Path | None,
        typer.Option("--data-root", help="folder holding tum/ \\[default: $CLIPCLIQUE_DATA or ./data]",
                     rich_help_panel=DATA_PANEL),
    ] = None,
) -> None:
    """Write SEQUENCE's annotations/ (to build its map) from instance masks made with another tool: a folder of
    instance PNGs (--masks, with --objects) or a COCO annotation file (--coco)."""
    from clipclique.datasets import open_sequence
    from clipclique.datasets.tum import TumSequence
    from clipclique.errors import ClipcliqueError
    from clipclique.exits import user_errors
    from clipclique.mapping.annotate import annotate as annotate_masks
    from clipclique.mapping.annotate import annotate_coco
    from clipclique.mapping.tables import make_console, print_annotated

    with user_errors(TOOL):
        opened = open_sequence(sequence, data_root)
        if not isinstance(opened, TumSequence):
            raise ClipcliqueError(f"{sequence}: a {opened.kind} scene; annotate writes the annotations of a TUM-format "
                                  "sequence (ScanNet scenes carry their own)")
        if (masks is None) == (coco is None):
            raise ClipcliqueError("annotate reads either --masks DIR (with --objects CSV) or --coco FILE")
        if masks is not None and objects is None:
            raise ClipcliqueError("--masks needs --objects CSV: the class and description of each id in the masks")
        done = annotate_masks(opened, masks, objects) if masks is not None else annotate_coco(opened, coco, objects)
    print_annotated(make_console(), done, sequence)


def main() -> None:
    one_blas_thread_by_default()  # numpy is not imported yet, so this takes effect (clipclique.blas)
    app()


if __name__ == "__main__":
    main()
