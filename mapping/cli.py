"""clipclique-map: build an object landmark map (ellipsoids + descriptions + CLIP text embeddings) of a scene.

Heavy modules (open3d, torch, rerun) are imported inside the command, so `--help` is instant.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

if TYPE_CHECKING:  # the real imports stay inside the command, so that --help is instant
    from rich.progress import Progress

    from clipclique.types import Map
    from mapping.build import BuildReport

app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode="rich",
                  context_settings={"help_option_names": ["-h", "--help"]})
console = Console(stderr=True, soft_wrap=not sys.stderr.isatty())  # piped: a path is never broken over two lines

DATA_PANEL = "Data"
OUTPUT_PANEL = "Output"


def _print_version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        print(f"clipclique-map {version('clipclique')}")
        raise typer.Exit()


@app.callback()
def _tool(version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                                help="print the version and exit")] = False) -> None:
    """clipclique-map: build object landmark maps of ScanNet scenes, TUM RGB-D sequences and the demo."""


@app.command()
def build(
    scene: Annotated[str, typer.Argument(help="scene0002_00, fr2, fr3, demo, demo_tum, demo_apartment, demo_desk, or a scene folder", show_default=False)],
    data_root: Annotated[
        Path | None,
        typer.Option("--data-root", help="folder holding scannet/scans/, tum/, demo/ \\[default: $CLIPCLIQUE_DATA or ./data]", rich_help_panel=DATA_PANEL),
    ] = None,
    out: Annotated[
        Path | None, typer.Option("--out", help="map file \\[default: outputs/maps/<SCENE>.map.npz]", rich_help_panel=OUTPUT_PANEL)
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
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="do not write the .rrd recording", rich_help_panel=OUTPUT_PANEL)] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="print only where the map is", rich_help_panel=OUTPUT_PANEL)] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="also print every landmark", rich_help_panel=OUTPUT_PANEL)] = False,
) -> None:
    """Build the landmark map of SCENE: one ellipsoid per object (walls, floors, ceilings left out)."""
    from clipclique.errors import ClipcliqueError, one_line

    try:
        run_build(scene, data_root, out, encoder, not no_rrd, verbosity=verbose - quiet)
    except ClipcliqueError as error:
        console.print(f"[bold red]error:[/] {escape(one_line(error))}", soft_wrap=True, highlight=False)
        raise typer.Exit(2) from None
    except KeyboardInterrupt:
        console.print("clipclique-map: interrupted", highlight=False)
        raise typer.Exit(130) from None


def run_build(scene: str, data_root: Path | None, out: Path | None, encoder_spec: str | None, rrd: bool,
              verbosity: int = 0) -> Path:
    """Open the scene, fit the landmarks, embed the descriptions, write the map (and .rrd).
    `verbosity` -1 prints only the outputs, 1 adds every landmark."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from clipclique.commands import rerun_hint
    from clipclique.backends import load_encoder
    from clipclique.datasets import scene_name
    from clipclique.resolve import open_scene
    from clipclique.mapfile import save_map
    from clipclique.outputs import Staging
    from mapping.build import build_map

    started = time.perf_counter()
    out = out or Path("outputs") / "maps" / f"{scene_name(scene)}.map.npz"  # the name typed, as clipclique-loc looks it up
    recording = out.with_name(out.name.removesuffix(".npz") + ".rrd")
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Staging() as staging:
        staged_map = staging.path(out)  # a folder in the way is refused before the work
        staged_recording = staging.path(recording) if rrd else None
        with Progress(*columns, console=console, transient=True, disable=verbosity < 0) as progress:
            sequence = open_scene(scene, data_root, _bar_on_first_call(progress, f"generating the {scene} data (first use)"))
            spec = encoder_spec or ("simulated" if sequence.synthetic else "auto")
            loaded = load_encoder(spec)
            task = progress.add_task("fitting ellipsoids", total=None)
            map, report = build_map(sequence, loaded, progress=lambda done, total: progress.update(task, completed=done, total=total))
        save_map(map, staged_map)
        if staged_recording is not None:
            from clipclique.viz import write_map_recording

            cloud = sequence.scene_cloud()
            write_map_recording(staged_recording, map, *(cloud or (None, None)), description=describe(map, sequence.name))
        stale = recording if staged_recording is None and recording.is_file() else None
        if stale:
            staging.remove(stale)
        staging.commit()
    report.timings["total"] = time.perf_counter() - started
    if verbosity >= 0:
        print_summary(map, report, spec)
    if verbosity > 0:
        print_landmarks(map)
    where = f"map: {out}" + (f"\nrecording: {recording}  ({rerun_hint(recording)})" if rrd else "")
    console.print(escape(where), highlight=False)
    if stale:
        console.print(f"removed {escape(str(stale))}, the recording of an earlier map (--no-rrd)", highlight=False)
    return out


def _bar_on_first_call(progress: Progress, description: str) -> Callable[[int, int], None]:
    """A progress callback whose bar appears only once there is work (the demo data may exist already)."""
    task = None

    def update(done: int, total: int) -> None:
        nonlocal task
        if task is None:
            task = progress.add_task(description, total=total)
        progress.update(task, completed=done, total=total)

    return update


def describe(map: Map, scene: str) -> str:
    """The recording's text document: what the map is and what made it."""
    source = map.provenance.get("source", {})
    simulated = " (simulated CLIP: a stand-in for real CLIP on synthetic data)" if map.provenance.get("encoder_simulated") else ""
    return (
        f"# Map of {scene}\n\n{len(map)} landmarks, {len(map.class_names)} classes, from a {source.get('kind', '?')} "
        f"scene{' (synthetic demo)' if source.get('synthetic') else ''}.\n\nText embeddings: {map.encoder}{simulated}.\n\n"
        f"Left out as structure: {', '.join(map.provenance.get('structure_left_out', []))}."
    )


def print_summary(map: Map, report: BuildReport, spec: str) -> None:
    """The landmarks per class, what was left out or skipped and why, the encoder and times."""
    table = Table(title=f"{len(map)} landmarks", title_justify="left")
    table.add_column("class")
    table.add_column("landmarks", justify="right")
    for name in map.class_names:
        table.add_row(escape(name), str(report.landmarks_per_class[name]))
    console.print(table)
    print_graph(map)
    if report.structure:
        console.print(escape("left out as structure: " + ", ".join(f"{name} x{n}" for name, n in sorted(report.structure.items()))))
    for reason, items in report.skipped.items():
        console.print(escape(f"skipped {len(items)}, {reason}: {', '.join(items)}"), highlight=False)
    if map.encoder == "none":
        why = "no CLIP weights found (--encoder auto)" if spec == "auto" else "--encoder none"
        console.print(f"text embeddings: none ({why}); localization will rank by Semantic Histograms only")
    else:
        simulated = " [yellow](simulated)[/]" if map.provenance.get("encoder_simulated") else ""
        console.print(f"text embeddings: {escape(map.encoder)}{simulated}")
    timings = ", ".join(f"{k} {v:.1f} s" for k, v in report.timings.items())
    console.print(f"time: {timings}")


def print_landmarks(map: Map) -> None:
    """Every landmark: instance id, class, centre and semi-axes (m), description."""
    for i in range(len(map)):
        center = " ".join(f"{v:.2f}" for v in map.ellipsoids.centers[i])
        axes = " ".join(f"{v:.2f}" for v in map.ellipsoids.axes[i])
        console.print(f"{map.instance_ids[i]:>4} {map.class_names[map.class_ids[i]]}: centre {center}, "
                      f"semi-axes {axes}, {map.descriptions[i]!r}", highlight=False, markup=False)


def print_graph(map: Map) -> None:
    """The semantic graph's degree histogram at the default d_adj: how much the Semantic Histograms can say."""
    from clipclique.config import GraphConfig
    from mapping.build import degree_histogram

    d_adj = GraphConfig().d_adj
    counts = degree_histogram(map, d_adj)
    console.print(f"semantic graph at d_adj {d_adj:g} m, landmarks per degree (0, 1, 2, ...): "
                  f"{', '.join(str(int(n)) for n in counts)}; {counts[0] / max(len(map), 1):.0%} isolated "
                  "(no neighbour: their Semantic Histograms are empty)", highlight=False)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
