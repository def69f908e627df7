"""Terminal tables of results documents: the paper's columns, and where each frame's time went."""

from __future__ import annotations

import sys
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from localization.results import ALL_STAGES


def make_console() -> Console:
    """A console that does not squeeze the tables to 80 columns when output goes to a file or pipe."""
    return Console() if sys.stdout.isatty() else Console(width=200)


def _number(value: float | None, digits: int = 2, scale: float = 1.0) -> str:
    return "-" if value is None else f"{scale * value:.{digits}f}"


def results_table(documents: list[dict[str, Any]], title: str = "Localization") -> Table:
    """One row per run: precision, recall, median TE/RE, success top-1/3/5 (%), time per query."""
    table = Table(title=title)
    for column in ("Sequence", "Method", "Frames", "Precision", "Recall", "TE [m]", "RE [deg]", "Top-1 [%]",
                   "Top-3 [%]", "Top-5 [%]", "Time [ms]"):
        table.add_column(escape(column), justify="left" if column in ("Sequence", "Method") else "right")
    for document in documents:
        run, summary = document["run"], document["summary"]
        table.add_row(
            escape(run["sequence"]), escape(run["method_title"]), _number(summary["frames"], 0),
            _number(summary["precision"]), _number(summary["recall"]),
            _number(summary["te_median_m"]), _number(summary["re_median_deg"], 1),
            *(_number(summary[f"success@{k}"], 1, 100.0) for k in (1, 3, 5)),
            _number(summary["time_ms_median"], 1),
        )
    table.caption = ("TE/RE: medians over frames with a pose; Top-k: frames with a pose within "
                     "1 m among the k best (frames without one count as failures); time: matching + inliers + pose")
    return table


def stage_table(documents: list[dict[str, Any]]) -> Table:
    """Median milliseconds per frame of every stage, detector and encoder included."""
    table = Table(title=escape("Median time per frame [ms]"))
    table.add_column("Sequence")
    table.add_column("Method")
    for stage in ALL_STAGES:
        table.add_column(stage, justify="right")
    for document in documents:
        medians = document["summary"]["stage_ms_median"]
        table.add_row(escape(document["run"]["sequence"]), escape(document["run"]["method_title"]),
                      *(_number(medians[stage], 1) for stage in ALL_STAGES))
    return table


def run_banner(document: dict[str, Any]) -> str:
    """Which detector and encoder ran, flagged when simulated, and the run's notes."""
    run = document["run"]
    detector = run["detector"]
    encoder = run["encoder"]
    lines = [
        f"detector: {detector['name']}{' (SIMULATED)' if detector['simulated'] else ''}",
        "encoder: none" if encoder is None else f"encoder: {encoder['name']}{' (SIMULATED)' if encoder['simulated'] else ''}",
    ]
    lines += [f"note: {note}" for note in run["notes"]]
    return "\n".join(lines)


def print_documents(console: Console, documents: list[dict[str, Any]]) -> None:
    """What ran (once per distinct banner), the results table and the stage timings."""
    for banner in dict.fromkeys(run_banner(d) for d in documents):
        console.print(escape(banner), highlight=False)
    console.print(results_table(documents))
    console.print(stage_table(documents))
