"""Terminal tables of results documents: the paper's columns, and where each frame's time went.

One pair of tables per sequence, its name on a line of its own above them, so that both fit an
80-column terminal whatever the sequence is called (real TUM names run to 44 characters). Into a
file or pipe a table is printed at its full width, never cut. Runs that differ in more than the
method (an override, a config file, another detector) are marked (a), (b), ... and the settings
of each mark are listed below.
"""

from __future__ import annotations

import sys
from string import ascii_lowercase
from typing import Any

from rich import box
from rich.console import Console, RenderableType
from rich.markup import escape
from rich.measure import Measurement
from rich.table import Table

from clipclique.config import LocalizationConfig
from clipclique.metrics import SUCCESS_THRESHOLDS_M
from clipclique.outcomes import ALL_STAGES, Stage

STAGE_HEADERS = {Stage.DETECTOR: "det.", Stage.OBSERVATIONS: "fit", Stage.ENCODER: "enc.", Stage.DESCRIPTORS: "desc.",
                 Stage.SIMILARITY: "sim.", Stage.MATCHING: "match", Stage.INLIERS: "inl.", Stage.POSE: "pose",
                 Stage.VERIFICATION: "verif"}  # 80 columns


def make_console() -> Console:
    """A console for the tables: the terminal's width, 80 columns into a file or pipe (print paths with
    soft_wrap=True, so that they are never broken over two lines)."""
    return Console() if sys.stdout.isatty() else Console(width=80)


def print_whole(console: Console, renderable: RenderableType) -> None:
    """Print `renderable`; into a file or pipe at its natural width when that exceeds the console's, so
    that no cell is cut to `…` (a terminal keeps its own width). The console is widened for the call: rich
    caps `print(width=...)` at the console's width."""
    if console.is_terminal:
        console.print(renderable)
        return
    unbounded = console.options.update_width(1 << 16)
    width, console.width = console.width, max(console.width, Measurement.get(console, unbounded, renderable).maximum)
    try:
        console.print(renderable)
    finally:
        console.width = width


def _number(value: float | None, digits: int = 2, scale: float = 1.0) -> str:
    return "-" if value is None else f"{scale * value:.{digits}f}"


def _milliseconds(value: float | None) -> str:
    """At most 5 characters up to 100 s: one decimal below 100 ms, none above (a column of 80)."""
    return _number(value, 1 if value is None or value < 100 else 0)


def _compact(title: str) -> Table:
    """A table with one space between columns and no side borders."""
    return Table(title=escape(title), box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, padding=(0, 0))


def _inputs(run: dict[str, Any]) -> dict[str, Any]:
    """The run's inputs, those left at their default (all frames, every frame) as None."""
    return {"detector": run["detector"]["name"], "encoder": (run["encoder"] or {}).get("name"),
            "map": run.get("map"), "stride": run.get("stride") if run.get("stride", 1) != 1 else None,
            "max_frames": run.get("max_frames"), "window": _window(run)}


def _window(run: dict[str, Any]) -> str | None:
    """`K/S odometry` of a windowed run (its odometry's name says when it is simulated), None for single frames."""
    window = run.get("window")
    return None if window is None else f"{window['size']}/{window['step']} {window['odometry']['name']}"


def run_settings(document: dict[str, Any], documents: list[dict[str, Any]]) -> str:
    """What sets a run apart: its settings changed from the method's preset, and the inputs (detector,
    encoder, map, frames) in which it differs from runs of the same method and sequence in the table; an
    input left at its default (all frames) is not named."""
    run = document["run"]
    changed = [f"{key}={value}" for key, value in run.get("changed", {}).items()]
    peers = [d["run"] for d in documents if (d["run"]["sequence"], d["run"]["method_title"])
             == (run["sequence"], run["method_title"])]
    for key, value in _inputs(run).items():
        if value is not None and any(_inputs(peer).get(key) != value for peer in peers):
            changed.append(f"{key}={value}")
    return " ".join(changed)


def _marks(documents: list[dict[str, Any]]) -> tuple[list[str], list[str]]:
    """Per document its method title with a mark for its settings, e.g. `CLIP-Clique (a)`; and the legend."""
    settings = [run_settings(d, documents) for d in documents]
    letters = {s: ascii_lowercase[i % 26] for i, s in enumerate(dict.fromkeys(s for s in settings if s))}
    titles = [d["run"]["method_title"] + (f" ({letters[s]})" if s else "") for d, s in zip(documents, settings)]
    return titles, [f"({letter}) {s}" for s, letter in letters.items()]


def _threshold(document: dict[str, Any]) -> float:
    """The translation error under which the run counted a pose as a success (metres)."""
    return float(document["run"].get("changed", {}).get("success_threshold_m",
                                                        LocalizationConfig().success_threshold_m))


def results_caption(documents: list[dict[str, Any]]) -> str:
    """What the results table's columns mean, with the success threshold the runs used."""
    thresholds = sorted({_threshold(d) for d in documents})
    within = (f"within {thresholds[0]:g} m" if len(thresholds) == 1 else
              f"within the run's success threshold ({', '.join(f'{t:g}' for t in thresholds)} m: see the marks)")
    return (f"TE/RE: medians over frames with a pose (mean, p90: their mean and 90th percentile). Posed: frames with a "
            f"pose, scored or not; {', '.join(f'{t:g}' for t in SUCCESS_THRESHOLDS_M)}: its translation error within "
            f"that many metres (a terminal too narrow for them all drops the outer two). Top-k [%]: frames "
            f"with a pose {within} among the k best (frames without one count as failures). ms: matching + inliers + "
            "pose per query.")


def results_table(documents: list[dict[str, Any]], titles: list[str] | None = None) -> Table:
    """One row per run (runs of one sequence): precision, recall, median TE/RE, success top-1/3/5 (%), time per
    query. `titles`: the method column, marked among a wider set of runs; default: marked among these."""
    table = _compact("Localization")
    for column in ("Method", "Frames", "Prec.", "Rec.", "TE [m]", "RE [°]", "Top-1", "Top-3", "Top-5", "ms"):
        table.add_column(escape(column), justify="left" if column == "Method" else "right", no_wrap=True)
    for document, method in zip(documents, titles or _marks(documents)[0]):
        summary = document["summary"]
        table.add_row(
            escape(method), str(int(summary["frames"])),
            _number(summary["precision"]), _number(summary["recall"]),
            _number(summary["te_median_m"]), _number(summary["re_median_deg"], 1),
            *(_number(summary[f"success@{k}"], 1, 100.0) for k in (1, 3, 5)),
            _number(summary["time_ms_median"], 1),
        )
    return table


def accuracy_table(documents: list[dict[str, Any]], titles: list[str] | None = None,
                   thresholds: tuple[float, ...] = SUCCESS_THRESHOLDS_M) -> Table:
    """The top-1 pose of each run (runs of one sequence): the frames that got one (%, ground truth or not), its
    success within each of `thresholds` (%, frames without a pose count as failures; '-' where a run from before
    that threshold has none) and the mean and 90th percentile of its translation error, the mean of its rotation
    error."""
    table = _compact("Top-1 pose [%], its errors")
    table.add_column("Method", no_wrap=True)
    table.add_column("Posed", justify="right", no_wrap=True)
    for threshold in thresholds:
        table.add_column(f"{threshold:g}", justify="right", no_wrap=True)
    for column in ("TE mean", "TE p90", "RE mean"):
        table.add_column(column, justify="right", no_wrap=True)
    for document, method in zip(documents, titles or _marks(documents)[0]):
        summary = document["summary"]
        table.add_row(escape(method), _number(summary["localized"], 1, 100.0),
                      *(_number(summary["success_within_m"].get(f"{t:g}"), 1, 100.0) for t in thresholds),
                      _number(summary["te_mean_m"]), _number(summary["te_p90_m"]), _number(summary["re_mean_deg"], 1))
    return table


def fitting_accuracy_table(console: Console, documents: list[dict[str, Any]], titles: list[str]) -> Table:
    """The accuracy table at every threshold, or on a terminal too narrow for it (80 columns) without the outer
    two (0.05 and 5 m)."""
    table = accuracy_table(documents, titles)
    unbounded = console.options.update_width(1 << 16)
    if console.is_terminal and Measurement.get(console, unbounded, table).maximum > console.width:
        return accuracy_table(documents, titles, SUCCESS_THRESHOLDS_M[1:-1])
    return table


STAGE_CAPTION = ("Stages: det./enc.: detector/encoder; fit: observed ellipsoids from the detections; desc.: "
                 "descriptors; sim.: similarity; inl.: inliers; verif: verification")


def stage_table(documents: list[dict[str, Any]], titles: list[str] | None = None) -> Table:
    """Median milliseconds per frame of every stage, detector and encoder included (runs of one sequence)."""
    table = _compact("Median time per frame [ms]")
    table.add_column("Method", no_wrap=True)
    for stage in ALL_STAGES:
        table.add_column(STAGE_HEADERS[stage], justify="right", no_wrap=True)
    for document, method in zip(documents, titles or _marks(documents)[0]):
        medians = document["summary"]["stage_ms_median"]
        table.add_row(escape(method), *(_milliseconds(medians[stage]) for stage in ALL_STAGES))
    return table


def failure_line(document: dict[str, Any], title: str) -> str | None:
    """Why the run's frames without a pose have none, most frequent first (results.json's summary.failures)."""
    summary = document["summary"]
    failures = summary.get("failures") or {}
    if not failures:
        return None
    reasons = ", ".join(f"{count} {kind.replace('_', ' ')}" for kind, count in failures.items())
    return f"{title}: {sum(failures.values())} of {summary['frames']} frames without a pose: {reasons}"


def unscored_line(document: dict[str, Any], title: str) -> str | None:
    """When no frame has a ground-truth pose (a bag run without --groundtruth): say so, not a table of dashes alone.
    (Success is averaged over the frames with ground truth: null when there is none.)"""
    summary = document["summary"]
    if not summary["frames"] or summary.get("success@1") is not None:
        return None
    return f"{title}: no ground truth: poses written (poses.tum), not scored"


def run_banner(document: dict[str, Any]) -> str:
    """Which detector and encoder ran, flagged when simulated, and the run's notes."""
    run = document["run"]
    detector = run["detector"]
    encoder = run["encoder"]
    lines = [
        f"detector: {detector['name']}{' (SIMULATED)' if detector['simulated'] else ''}",
        "encoder: none" if encoder is None
        else f"encoder: {encoder['name']}{' (SIMULATED)' if encoder['simulated'] else ''}",
    ]
    if "window" in run:
        window = run["window"]
        odometry = window["odometry"]
        lines.append(f"window: {window['size']} frames, step {window['step']}; odometry: {odometry['name']}")
    lines += [f"note: {note}" for note in run["notes"]]
    return "\n".join(lines)


def print_documents(console: Console, documents: list[dict[str, Any]]) -> None:
    """What ran (once per distinct banner, under the runs it is of when there are several); per sequence its
    name, the results, accuracy and stage tables and why frames have no pose; what the columns mean; what each
    mark changed."""
    titles, legend = _marks(documents)
    banners = [run_banner(d) for d in documents]
    for banner in dict.fromkeys(banners):
        if len(set(banners)) > 1:  # tie each to its runs
            runs = [f"{d['run']['sequence']} {title}" for d, title, b in zip(documents, titles, banners) if b == banner]
            console.print(escape(f"runs: {', '.join(runs)}"), highlight=False, soft_wrap=True)
        console.print(escape(banner), highlight=False, soft_wrap=True)  # notes name paths: never broken
    for sequence in dict.fromkeys(d["run"]["sequence"] for d in documents):
        rows = [i for i, d in enumerate(documents) if d["run"]["sequence"] == sequence]
        console.print()
        console.print(f"[bold]{escape(sequence)}[/]", highlight=False, soft_wrap=True)
        print_whole(console, results_table([documents[i] for i in rows], [titles[i] for i in rows]))
        print_whole(console, fitting_accuracy_table(console, [documents[i] for i in rows], [titles[i] for i in rows]))
        print_whole(console, stage_table([documents[i] for i in rows], [titles[i] for i in rows]))
        for i in rows:
            if line := failure_line(documents[i], titles[i]):
                console.print(escape(line), highlight=False, soft_wrap=not console.is_terminal)  # piped: whole
            if line := unscored_line(documents[i], titles[i]):
                console.print(escape(line), highlight=False, soft_wrap=not console.is_terminal)
    console.print()
    for caption in (results_caption(documents), STAGE_CAPTION):
        console.print(caption, highlight=False, markup=False)  # prose: wraps at the console's width
    for line in legend:
        console.print(line, highlight=False, markup=False, soft_wrap=True)  # settings name paths: never broken


def print_frames(console: Console, document: dict[str, Any]) -> None:
    """One line per frame: observations, and the top-1 translation error or why there is no pose."""
    for frame in document["frames"]:
        error = frame["evaluation"]["translation_error_m"]
        outcome = (f"no pose: {frame['failure']}" if frame["failure"] is not None else
                   "pose (no ground truth)" if error is None else f"TE {error:.2f} m")
        # ScanNet: the number
        name = "" if frame["name"] == str(frame["index"]) else f" (image {escape(frame['name'])})"
        count = frame["observations"]
        console.print(f"frame {frame['index']}{name}: {count} observation{'' if count == 1 else 's'}, "
                      f"{escape(outcome)}", highlight=False, soft_wrap=True)


def print_survey(console: Console, survey: Any) -> None:
    """`clipclique-loc inspect`: a bag's topics (a clipclique.datasets.rosbag.Survey), one line each (names are
    long: never cut), then what a run would read and why, or why it cannot without a topic named."""
    console.print(escape(f"{survey.path}: {survey.duration_s:.1f} s, {len(survey.topics)} topics"), highlight=False,
                  soft_wrap=True)
    for topic in survey.topics:
        parts = [topic.name, topic.msgtype, f"{topic.count} messages", f"{topic.rate_hz:.1f} Hz"]
        parts += ([f"encoding {topic.encoding}"] * bool(topic.encoding)
                  + [f"frame {topic.frame_id}"] * bool(topic.frame_id))
        parts += [f"-> {topic.role}"] * bool(topic.role)
        console.print(escape("  " + "  ".join(parts)), highlight=False, soft_wrap=True)
    for reason in survey.reasons:
        console.print(f"reads {escape(reason)}", highlight=False, soft_wrap=True)
    if survey.problem:
        console.print(f"cannot read it as is: {escape(survey.problem)}", highlight=False, soft_wrap=True)
