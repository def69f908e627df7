"""clipclique-map: build an object landmark map (ellipsoids + descriptions + CLIP text embeddings) of a scene.

Heavy modules (open3d, torch, rerun) are imported inside the command, so `--help` is instant.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.table import Table

if TYPE_CHECKING:  # the real imports stay inside the command, so that --help is instant
    from clipclique.types import Map
    from mapping.build import BuildReport

app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode="rich", help=__doc__)
console = Console(stderr=True)

DATA_PANEL = "Data"
OUTPUT_PANEL = "Output"


@app.callback()
def _tool() -> None:
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
) -> None:
    """Build the landmark map of SCENE: one ellipsoid per object (walls, floors, ceilings left out)."""
    from clipclique.errors import ClipcliqueError

    try:
        run_build(scene, data_root, out, encoder, not no_rrd)
    except ClipcliqueError as error:
        console.print(f"[bold red]error:[/] {error}", soft_wrap=True, highlight=False)
        raise typer.Exit(2) from None


def run_build(scene: str, data_root: Path | None, out: Path | None, encoder_spec: str | None, rrd: bool) -> Path:
    """Open the scene, fit the landmarks, embed the descriptions, write the map (and .rrd)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from clipclique.datasets import demo, open_sequence, resolve_data_root
    from clipclique.encoders import load_encoder
    from clipclique.mapfile import save_map
    from mapping.build import build_map

    started = time.perf_counter()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True) as progress:
        if scene in demo.DEMO_SCENES:
            task = progress.add_task(f"generating the {scene} data (first use)", total=None)
            demo.ensure_demo(scene, resolve_data_root(data_root), lambda done, total: progress.update(task, completed=done, total=total))
        sequence = open_sequence(scene, data_root)
        spec = encoder_spec or ("simulated" if sequence.synthetic else "auto")
        loaded = load_encoder(spec)
        task = progress.add_task("fitting ellipsoids", total=None)
        map, report = build_map(sequence, loaded, progress=lambda done, total: progress.update(task, completed=done, total=total))

    out = out or Path("outputs") / "maps" / f"{Path(scene).name}.map.npz"  # the name typed, as clipclique-loc looks it up
    save_map(map, out)
    recording = out.with_name(out.name.removesuffix(".npz") + ".rrd")
    if rrd:
        from clipclique.viz import write_map_recording

        cloud = sequence.scene_cloud()
        write_map_recording(recording, map, *(cloud or (None, None)), description=describe(map, sequence.name))
    report.timings["total"] = time.perf_counter() - started
    print_summary(map, report, out, recording if rrd else None, spec)
    return out


def describe(map: Map, scene: str) -> str:
    """The recording's text document: what the map is and what made it."""
    source = map.provenance.get("source", {})
    simulated = " (simulated CLIP: a stand-in for real CLIP on synthetic data)" if map.provenance.get("encoder_simulated") else ""
    return (
        f"# Map of {scene}\n\n{len(map)} landmarks, {len(map.class_names)} classes, from a {source.get('kind', '?')} "
        f"scene{' (synthetic demo)' if source.get('synthetic') else ''}.\n\nText embeddings: {map.encoder}{simulated}.\n\n"
        f"Left out as structure: {', '.join(map.provenance.get('structure_left_out', []))}."
    )


def print_summary(map: Map, report: BuildReport, out: Path, recording: Path | None, spec: str) -> None:
    """The landmarks per class, what was left out or skipped and why, the encoder, times and outputs."""
    table = Table(title=f"{len(map)} landmarks", title_justify="left")
    table.add_column("class")
    table.add_column("landmarks", justify="right")
    for name in map.class_names:
        table.add_row(name, str(report.landmarks_per_class[name]))
    console.print(table)
    print_graph(map)
    if report.structure:
        console.print("left out as structure: " + ", ".join(f"{name} x{n}" for name, n in sorted(report.structure.items())))
    for reason, items in report.skipped.items():
        console.print(f"skipped {len(items)}, {reason}: {', '.join(items)}", highlight=False)
    if map.encoder == "none":
        why = "no CLIP weights found (--encoder auto)" if spec == "auto" else "--encoder none"
        console.print(f"text embeddings: none ({why}); localization will rank by Semantic Histograms only")
    else:
        simulated = " [yellow](simulated)[/]" if map.provenance.get("encoder_simulated") else ""
        console.print(f"text embeddings: {map.encoder}{simulated}")
    timings = ", ".join(f"{k} {v:.1f} s" for k, v in report.timings.items())
    console.print(f"time: {timings}")
    console.print(f"map: {out}" + (f"\nrecording: {recording}  (open with: rerun {recording})" if recording else ""), highlight=False)


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
