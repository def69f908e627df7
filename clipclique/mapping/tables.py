"""What `clipclique-map` prints: the landmarks per class, what was left out, how an import fits, where the files are."""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable

from rich.console import Console
from rich.markup import escape
from rich.progress import Progress
from rich.table import Table

from clipclique.commands import command, rerun_hint
from clipclique.config import GraphConfig
from clipclique.datasets.tum import MAX_TIME_DIFF
from clipclique.mapping.annotate import AnnotationReport
from clipclique.mapping.build import BuildReport, degree_histogram
from clipclique.mapping.run import Built, Exported, Imported
from clipclique.types import Map


def make_console() -> Console:
    """stderr; piped, a path is never broken over two lines."""
    return Console(stderr=True, soft_wrap=not sys.stderr.isatty())


def print_build(console: Console, built: Built, verbosity: int = 0) -> None:
    """The summary (verbosity 0), also every landmark (1), or only where the files are (-1)."""
    if verbosity >= 0:
        print_summary(console, built.map, built.report, built.encoder_spec)
    if verbosity > 0:
        print_landmarks(console, built.map)
    where = f"map: {built.out}"
    if built.recording is not None:
        where += f"\nrecording: {built.recording}  ({rerun_hint(built.recording)})"
    console.print(escape(where), highlight=False)
    if built.stale:
        console.print(escape(f"note: {built.stale} is an earlier map's recording and does not show this map (--no-rrd "
                             "leaves it as it is; build without --no-rrd to replace it)"), highlight=False)


def print_annotated(console: Console, done: AnnotationReport, sequence: str) -> None:
    """What `clipclique-map annotate` wrote, which annotations the map cannot use, and the next command."""
    console.print(escape(f"annotations: {done.folder}/ ({done.frames} frames, {done.objects} objects)"),
                  highlight=False)
    if done.without_pose:
        console.print(escape(f"{len(done.without_pose)} annotated frames have no ground-truth pose within "
                             f"{MAX_TIME_DIFF} s, so the map cannot use them: {', '.join(done.without_pose[:5])}"
                             + (", ..." if len(done.without_pose) > 5 else "")), highlight=False)
    if done.unseen:
        console.print(escape(f"objects no mask shows (no landmark for them): {', '.join(map(str, done.unseen))}"),
                      highlight=False)
    console.print(escape(f"next: {command('clipclique-map')} build {sequence}"), highlight=False)


def bar_on_first_call(progress: Progress, description: str) -> Callable[[int, int], None]:
    """A progress callback whose bar appears only once there is work (the demo data may exist already)."""
    task = None

    def update(done: int, total: int) -> None:
        nonlocal task
        if task is None:
            task = progress.add_task(description, total=total)
        progress.update(task, completed=done, total=total)

    return update


def print_summary(console: Console, map: Map, report: BuildReport, spec: str) -> None:
    """The landmarks per class, what was left out or skipped and why, the encoder and times."""
    held = [name for name in map.class_names if report.landmarks_per_class[name]]
    table = Table(title=f"{len(map)} landmarks, {len(held)} classes", title_justify="left")
    table.add_column("class")
    table.add_column("landmarks", justify="right")
    for name in held:
        table.add_row(escape(name), str(report.landmarks_per_class[name]))
    console.print(table)
    if len(held) < len(map.class_names):
        console.print(f"{len(map.class_names) - len(held)} more classes appear only in the class distributions",
                      highlight=False)
    print_graph(console, map)
    if report.structure:
        console.print(escape("left out as structure: "
                             + ", ".join(f"{name} x{n}" for name, n in sorted(report.structure.items()))))
    for reason, items in report.skipped.items():
        console.print(escape(f"skipped {len(items)}, {reason}: {', '.join(items)}"), highlight=False)
    if map.encoder == "none":
        why = "no CLIP weights found (--encoder auto)" if spec == "auto" else "--encoder none"
        console.print(f"text embeddings: none ({why}); localization will rank by Semantic Histograms only")
    else:
        simulated = " [yellow](simulated)[/]" if map.provenance.get("encoder_simulated") else ""
        console.print(f"text embeddings: {escape(map.encoder)}{simulated}")
    for note in report.notes:
        console.print(escape(f"note: {note}"), highlight=False)
    timings = ", ".join(f"{k} {v:.1f} s" for k, v in report.timings.items())
    console.print(f"time: {timings}")


def print_landmarks(console: Console, map: Map) -> None:
    """Every landmark: instance id, class, centre and semi-axes (m), description."""
    for i in range(len(map)):
        center = " ".join(f"{v:.2f}" for v in map.ellipsoids.centers[i])
        axes = " ".join(f"{v:.2f}" for v in map.ellipsoids.axes[i])
        console.print(f"{map.instance_ids[i]:>4} {map.class_names[map.class_ids[i]]}: centre {center}, "
                      f"semi-axes {axes}, {map.descriptions[i]!r}", highlight=False, markup=False)


def print_graph(console: Console, map: Map) -> None:
    """The semantic graph's degree histogram at the default d_adj: how much the Semantic Histograms can say."""
    d_adj = GraphConfig().d_adj
    counts = degree_histogram(map, d_adj)
    console.print(f"semantic graph at d_adj {d_adj:g} m, landmarks per degree (0, 1, 2, ...): "
                  f"{', '.join(str(int(n)) for n in counts)}; {counts[0] / max(len(map), 1):.0%} isolated "
                  "(no neighbour: their Semantic Histograms are empty)", highlight=False)


def print_import(console: Console, imported: Imported, quiet: bool = False) -> None:
    """What was read, its notes, how it fits the ground truth, the landmarks, where the files are."""
    report, map = imported.report, imported.report.map
    if not quiet:
        console.print(f"read {len(map)} objects from {escape(str(imported.path))} ({report.imported.source})"
                      + (", with class distributions" if map.class_distributions is not None else ""), highlight=False)
        for note in report.imported.notes:
            console.print(f"note: {escape(note)}", highlight=False)
        if report.alignment is not None:
            fit = report.alignment
            console.print(f"aligned to {escape(report.sequence_name or 'the ground truth')}: {fit.matched} keyframes "
                          f"matched, RMSE {fit.rmse_m * 100:.2f} cm, scale {fit.transform.scale:.4f} "
                          f"({'similarity' if fit.with_scale else 'rigid'})", highlight=False)
        elif report.sequence_name is not None:
            console.print(f"in the frame of {escape(report.sequence_name)}, as the file says", highlight=False)
        else:
            console.print("not aligned: the map stays in its own frame (clipclique-loc run needs --same-place; "
                          "align it with --align-to SEQUENCE)", highlight=False)
        summary = BuildReport(Counter(map.class_names[c] for c in map.class_ids), encoder=map.encoder)
        summary.timings["total"] = imported.seconds
        print_summary(console, map, summary, imported.encoder_spec)
    where = f"map: {imported.out}"
    if imported.recording is not None:
        where += f"\nrecording: {imported.recording}  ({rerun_hint(imported.recording)})"
    console.print(escape(where), highlight=False)


def print_export(console: Console, exported: Exported) -> None:
    console.print(f"wrote {exported.written} landmarks to {escape(str(exported.out))}", highlight=False)
    if exported.renamed:
        console.print("written as their COCO class: "
                      + escape(", ".join(f"{a} as {b}" for a, b in exported.renamed.items())),
                      highlight=False)
    if exported.unwritable:
        console.print(f"left out {exported.left_out} landmarks of classes an OA-SLAM map cannot hold (not COCO): "
                      f"{escape(', '.join(exported.unwritable))}", highlight=False)
