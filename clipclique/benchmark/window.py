"""Window localization measured: top-1 success for windows of K frames, exact and drifting odometry.

    .venv/bin/python tools/bench_window.py                       # demo_desk and demo_apartment, K = 1 3 5 10
    .venv/bin/python tools/bench_window.py demo_desk --sizes 1 10 --drifts 1 --step 2

Each scene's frames go through the detector, the observation fit and the encoder once (clipclique.benchmark.suite's
cache); every window of K frames ending at each frame (every S-th frame back, the first frames with the
shorter window they have) is fused (`clipclique.multiframe.window.fuse`) with odometry from ground truth, exact or
with the simulated drift of `clipclique.multiframe.odometry.drifting`, and localized as one query. Two
configurations: CLIP-Clique as shipped (simulated CLIP), and Semantic Histograms only (alpha = 0).
Prints each run's success within every threshold (metrics.SUCCESS_THRESHOLDS_M), then one table at 0.5 and 1 m
(the issue's window targets); --json writes the figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from clipclique.benchmark.suite import CachedSequence, cache_sequence, ensure_map
from clipclique.config import LocalizationConfig, make_config
from clipclique.exits import user_errors
from clipclique.metrics import SUCCESS_THRESHOLDS_M, success_within
from clipclique.multiframe.odometry import drifting
from clipclique.multiframe.window import WindowConfig, Windower
from clipclique.pipeline import index_map, localize
from clipclique.pose.distance import pose_errors

TABLE_THRESHOLDS_M = (0.5, 1.0)  # the table's cells, per odometry: a subset of SUCCESS_THRESHOLDS_M
CONFIGS = {"CLIP-Clique": [], "SH only (alpha=0)": ["similarity.alpha=0"]}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="*", default=["demo_desk", "demo_apartment"])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 3, 5, 10], help="window sizes K")
    parser.add_argument("--drifts", type=float, nargs="+", default=[0.0, 1.0, 3.0], help="odometry drift, percent")
    parser.add_argument("--step", type=int, default=1, help="S: every S-th frame back from the newest")
    parser.add_argument("--seed", type=int, default=0, help="of the simulated drift")
    parser.add_argument("--data-root", type=Path, help="datasets folder [default: $CLIPCLIQUE_DATA or ./data]")
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser.parse_args(argv)


def window_success(sequence: CachedSequence, config: LocalizationConfig, window: WindowConfig,
                   drift: float, seed: int) -> dict[str, float]:
    """Top-1 success within each threshold over the frames with ground truth, and the mean observations per query."""
    frames = sequence.frames
    windower = Windower(window, drifting([frame.gt_pose for frame in frames], drift, seed).poses,
                        sequence.map.class_names)
    index = index_map(sequence.map, config)
    errors, sizes, dropped = [], [], 0
    for newest, frame in enumerate(frames):
        query = windower.query(newest, frame.observations, lambda i: frames[i].observations)
        dropped += query.without_odometry
        result = localize(query.observations, index, config)
        sizes.append(len(query.observations))
        if frame.gt_pose is not None:
            errors.append(pose_errors(result.hypotheses[0].pose, frame.gt_pose)[0] if result.hypotheses else None)
    return {**{f"within_{t}m": share for t, share in success_within(errors).items()},
            "observations_mean": float(np.mean(sizes)), "frames": len(errors), "dropped_frames": dropped}


def measure(args: argparse.Namespace) -> None:
    rows = []
    for scene in args.scenes:
        ensure_map(scene, args.data_root)
        print(f"{scene}: detecting and fitting every frame once ...", file=sys.stderr)
        sequence = cache_sequence(scene, args.data_root, None, lambda total: None)
        for title, overrides in CONFIGS.items():
            config = make_config("clipclique", overrides=overrides)
            for size in args.sizes:
                for drift in (args.drifts if size > 1 else [0.0]):
                    window = WindowConfig(size=size, step=args.step)
                    figures = window_success(sequence, config, window, drift, args.seed)
                    rows.append({"scene": scene, "config": title, "K": size, "S": args.step, "drift_percent": drift,
                                 **figures})
                    print(_row(rows[-1]), flush=True)
    print("\n" + table(rows))
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "seed": args.seed}, indent=1))


def _row(row: dict) -> str:
    return (f"{row['scene']:15s} {row['config']:18s} K={row['K']:<3d} drift={row['drift_percent']:g}% "
            + " ".join(f"<{t:g} m {100 * row[f'within_{t:g}m']:5.1f}%" for t in SUCCESS_THRESHOLDS_M)
            + f"  obs {row['observations_mean']:.1f}")


def table(rows: list[dict]) -> str:
    """Markdown: one line per scene, configuration and K; per odometry, top-1 within TABLE_THRESHOLDS_M (%)."""
    drifts = sorted({row["drift_percent"] for row in rows})
    within = " / ".join(f"<{t:g} m" for t in TABLE_THRESHOLDS_M)
    head = "| scene | similarity | K | " + " | ".join(
        ("exact odometry" if d == 0 else f"{d:g}% drift (simulated)") + f" {within}" for d in drifts) + " |"
    lines = [head, "|" + "---|" * (3 + len(drifts))]
    keys = dict.fromkeys((row["scene"], row["config"], row["K"]) for row in rows)
    for scene, config, size in keys:
        cells = []
        for drift in drifts:
            found = [r for r in rows if (r["scene"], r["config"], r["K"]) == (scene, config, size)
                     and (r["drift_percent"] == drift or size == 1)]
            cells.append(" / ".join(f"{100 * found[0][f'within_{t:g}m']:.1f}" for t in TABLE_THRESHOLDS_M)
                         if found else "-")
        lines.append(f"| {scene} | {config} | {size} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    with user_errors("bench_window"):
        measure(args)
