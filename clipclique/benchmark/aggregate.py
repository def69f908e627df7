"""The benchmark's aggregate outputs beside its run folders: summary.json (every run's summary and
every failed run), report.md (clipclique-loc's tables of all runs, the failures) and success.png.
They are staged and appear together (clipclique.io.outputs)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

from rich.console import Console

from clipclique.benchmark.engine import BenchResult
from clipclique.io.outputs import Staging
from clipclique.localization.results import json_safe
from clipclique.localization.tables import print_documents

SUMMARY_FORMAT = "clipclique-bench summary"


def write(result: BenchResult, out: Path, command: str) -> None:
    rows = [{"sequence": d["run"]["sequence"], "run": d["run"]["name"], "method": d["run"]["method"],
             "changed": d["run"]["changed"], "summary": d["summary"]} for d in result.documents]
    summary = json_safe({"format": SUMMARY_FORMAT, "version": 1, "command": command, "runs": rows,
                         "failed": result.failed, "skipped_finished": result.skipped, "tasks": result.tasks,
                         "wall_time_s": result.wall_s})
    out.mkdir(parents=True, exist_ok=True)
    with Staging() as staging:
        staging.path(out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False), encoding="utf-8")
        staging.path(out / "report.md").write_text(markdown(result, command), encoding="utf-8")
        if result.documents:
            plot_success(result.documents, staging.path(out / "success.png"))
        else:
            staging.remove(out / "success.png")  # an earlier run's figure would not match
        staging.commit()


def tables_text(documents: list[dict[str, Any]]) -> str:
    """clipclique-loc's tables of `documents`, as plain text."""
    console = Console(file=io.StringIO(), width=120, color_system=None)
    print_documents(console, documents)
    return console.file.getvalue()


def markdown(result: BenchResult, command: str) -> str:
    parts = ["# Benchmark", "", f"`{command}`", "",
             f"{len(result.documents)} runs ({result.skipped} found finished), {len(result.failed)} failed, "
             f"{result.tasks} tasks in {result.wall_s:.0f} s.", ""]
    if result.documents:
        parts += ["![success](success.png)", "", "```", tables_text(result.documents).rstrip(), "```", ""]
    if result.failed:
        parts += ["## Failed runs (not written; run the command again to retry them)", ""]
        parts += [f"- {row['sequence']} / {row['run']}: {'; '.join(row['reasons'])}" for row in result.failed]
    return "\n".join(parts) + "\n"


def plot_success(documents: list[dict[str, Any]], path: Path) -> None:
    """Top-1 success [%] of every run, grouped by sequence."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{d['run']['sequence']}\n{d['run']['name']}" for d in documents]
    values = [100.0 * (d["summary"]["success@1"] or 0.0) for d in documents]
    figure, axes = plt.subplots(figsize=(max(4.0, 0.5 * len(documents) + 2), 4))
    axes.bar(range(len(values)), values)
    axes.set_xticks(range(len(values)), labels, rotation=90, fontsize=6)
    axes.set_ylabel("top-1 success within 1 m [%]")
    axes.set_ylim(0, 100)
    figure.tight_layout()
    figure.savefig(path, dpi=120, format="png")
    plt.close(figure)
