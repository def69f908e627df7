"""Window localization measured: top-1 success for windows of K frames, exact and drifting odometry.

    .venv/bin/python tools/bench_window.py                       # demo_desk and demo_apartment, K = 1 3 5 10
    .venv/bin/python tools/bench_window.py demo_desk --sizes 1 10 --drifts 1 --step 2
    .venv/bin/python tools/bench_window.py demo_sparse --sizes 1 5 10 --drifts 0 1 --spans 1 3 6 --every-threshold

Each scene's frames go through the detector, the observation fit and the encoder once (clipclique.benchmark.suite's
cache); every window of K frames ending at each frame (every S-th frame back, the first frames with the
shorter window they have) is fused (`clipclique.multiframe.window.fuse`) with odometry from ground truth, exact or
with the simulated drift of `clipclique.multiframe.odometry.drifting`, and localized as one query. Two
configurations: CLIP-Clique as shipped (simulated CLIP), and Semantic Histograms only (alpha = 0).
`--spans SECONDS ...` (instead of --step) spreads each K over each span: the step `span_step` makes of it at the
measured frames' median interval, as `clipclique-loc run --window K --window-span SECONDS` does (K = 1: one
frame, no span). `--frames N` measures N frames spread over each scene (the window then steps over those: a span
shorter than K - 1 of their intervals is not kept); `--every N` scores every N-th frame as the newest, its windows
drawing on every frame (cheaper, and the spans kept); `--view sparse` (busy, few) scores only the newest frames of
that view (`suite.view_of`: 3-5 distinct mapped objects observed in the frame itself), their windows as ever.
Prints each run's success within every threshold (metrics.SUCCESS_THRESHOLDS_M), then one table at 0.5 and 1 m
(the issue's window targets; --every-threshold: at every threshold); --json writes the figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from clipclique.benchmark.suite import VIEWS, CachedSequence, cache_sequence, ensure_map, view_of
from clipclique.config import LocalizationConfig, make_config
from clipclique.exits import user_errors
from clipclique.metrics import SUCCESS_THRESHOLDS_M, success_within
from clipclique.multiframe.odometry import drifting
from clipclique.multiframe.window import WindowConfig, Windower, span_step
from clipclique.pipeline import index_map, localize
from clipclique.pose.distance import pose_errors

TABLE_THRESHOLDS_M = (0.5, 1.0)  # the table's cells, per odometry: a subset of SUCCESS_THRESHOLDS_M
CONFIGS = {"CLIP-Clique": [], "SH only (alpha=0)": ["similarity.alpha=0"]}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="*", default=["demo_desk", "demo_apartment"])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 3, 5, 10], help="window sizes K")
    parser.add_argument("--drifts", type=float, nargs="+", default=[0.0, 1.0, 3.0], help="odometry drift, percent")
    spacing = parser.add_mutually_exclusive_group()
    spacing.add_argument("--step", type=int, help="S: every S-th frame back from the newest [default: 1]")
    spacing.add_argument("--spans", type=float, nargs="+", metavar="SECONDS",
                         help="spread each K over each of these spans (the step span_step makes of it)")
    parser.add_argument("--frames", type=int, help="frames per scene, spread evenly [default: all]")
    parser.add_argument("--every", type=int, default=1, metavar="N",
                        help="score every N-th frame as the newest, windows drawing on all frames [default: 1]")
    parser.add_argument("--view", choices=VIEWS, default="all",
                        help="score only the newest frames of this view (suite.view_of) [default: all]")
    parser.add_argument("--every-threshold", action="store_true",
                        help="the table at every threshold, not only at 0.5 and 1 m")
    parser.add_argument("--seed", type=int, default=0, help="of the simulated drift")
    parser.add_argument("--data-root", type=Path, help="datasets folder [default: $CLIPCLIQUE_DATA or ./data]")
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser.parse_args(argv)


def window_success(sequence: CachedSequence, config: LocalizationConfig, window: WindowConfig,
                   drift: float, seed: int, every: int = 1, view: str = "all") -> dict[str, float]:
    """Top-1 success within each threshold over the frames with ground truth (every `every`-th as the newest, of
    `view` only: suite.VIEWS), and the mean observations per query."""
    frames = sequence.frames
    windower = Windower(window, drifting([frame.gt_pose for frame in frames], drift, seed).poses,
                        sequence.map.class_names)
    index = index_map(sequence.map, config)
    errors, sizes, dropped = [], [], 0
    for newest, frame in enumerate(frames):
        if newest % every or (view != "all" and view_of(frame.observations, sequence.map) != view):
            continue
        query = windower.query(newest, frame.observations, lambda i: frames[i].observations)
        dropped += query.without_odometry
        result = localize(query.observations, index, config)
        sizes.append(len(query.observations))
        if frame.gt_pose is not None:
            errors.append(pose_errors(result.hypotheses[0].pose, frame.gt_pose)[0] if result.hypotheses else None)
    return {**{f"within_{t}m": share for t, share in success_within(errors).items()},
            "observations_mean": float(np.mean(sizes)), "frames": len(errors), "dropped_frames": dropped}


def frame_times(sequence: CachedSequence) -> np.ndarray:
    """(F,) the timestamps of the cached frames (those a window steps over)."""
    times = sequence.run.sequence.trajectory()[0]
    return np.asarray(times, float)[[frame.index for frame in sequence.frames]]


def spacings(size: int, step: int | None, spans: list[float] | None,
             times: np.ndarray) -> list[tuple[float | None, int]]:
    """(span in seconds or None, step S) for each window of `size` frames: `--step` as given (1 by default), or each
    of `--spans` made a step by `span_step` at `times`' median interval; K = 1 one frame, whatever the spans."""
    if not spans or size < 2:
        return [(None, step or 1)]
    return [(span, span_step(span, size, times)) for span in spans]


def measure(args: argparse.Namespace) -> None:
    rows = []
    for scene in args.scenes:
        ensure_map(scene, args.data_root)
        print(f"{scene}: detecting and fitting every frame once ...", file=sys.stderr)
        sequence = cache_sequence(scene, args.data_root, args.frames, lambda total: None)
        times = frame_times(sequence)
        for title, overrides in CONFIGS.items():
            config = make_config("clipclique", overrides=overrides)
            for size in args.sizes:
                for span, step in spacings(size, args.step, args.spans, times):
                    for drift in (args.drifts if size > 1 else [0.0]):
                        window = WindowConfig(size=size, step=step)
                        figures = window_success(sequence, config, window, drift, args.seed, args.every, args.view)
                        rows.append({"scene": scene, "view": args.view, "config": title, "K": size, "S": step,
                                     "span_s": span, "drift_percent": drift, **figures})
                        print(_row(rows[-1]), flush=True)
    print("\n" + table(rows, SUCCESS_THRESHOLDS_M if args.every_threshold else TABLE_THRESHOLDS_M))
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "seed": args.seed}, indent=1))


def _row(row: dict) -> str:
    span = "" if row.get("span_s") is None else f" span={row['span_s']:g}s"
    return (f"{row['scene']:15s} {row['config']:18s} K={row['K']:<3d} S={row['S']:<3d}{span} "
            f"drift={row['drift_percent']:g}% "
            + " ".join(f"<{t:g} m {100 * row[f'within_{t:g}m']:5.1f}%" for t in SUCCESS_THRESHOLDS_M)
            + f"  obs {row['observations_mean']:.1f}")


def table(rows: list[dict], thresholds: tuple[float, ...] = TABLE_THRESHOLDS_M) -> str:
    """Markdown: one line per scene, configuration and K (and span and step S, when a row has a span); per
    odometry, top-1 within `thresholds` (%)."""
    drifts = sorted({row["drift_percent"] for row in rows})
    spans = any(row.get("span_s") is not None for row in rows)
    within = " / ".join(f"<{t:g} m" for t in thresholds)
    head = "| scene | similarity | K | " + ("span | S | " if spans else "") + " | ".join(
        ("exact odometry" if d == 0 else f"{d:g}% drift (simulated)") + f" {within}" for d in drifts) + " |"
    lines = [head, "|" + "---|" * (3 + 2 * spans + len(drifts))]
    keys = dict.fromkeys((row["scene"], row["config"], row["K"], row.get("span_s"), row["S"]) for row in rows)
    for scene, config, size, span, step in keys:
        cells = []
        for drift in drifts:
            found = [r for r in rows if (r["scene"], r["config"], r["K"], r.get("span_s"), r["S"])
                     == (scene, config, size, span, step) and (r["drift_percent"] == drift or size == 1)]
            cells.append(" / ".join(f"{100 * found[0][f'within_{t:g}m']:.1f}" for t in thresholds)
                         if found else "-")
        spacing = ("- | - | " if span is None else f"{span:g} s | {step} | ") if spans else ""
        lines.append(f"| {scene} | {config} | {size} | {spacing}" + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    with user_errors("bench_window"):
        measure(args)
