"""The partial-view slack settings side by side on the generated scenes: top-1/top-5 % within 1 m,
fused (0.7 CLIP + 0.3 SH) and SH only. Gives the table of README "Beyond the paper".

    .venv/bin/python tools/sweep_slack.py demo_apartment demo_desk demo demo_tum
"""

from __future__ import annotations

import sys

from clipclique.benchmark import suite as bench

SETTINGS = {
    "none": {"inliers.partial_slack": 0.0},
    "deficit >= 0.3 m, x1.0, cap 0.6 m": {"inliers.slack_min_deficit": 0.3, "inliers.partial_slack": 1.0,
                                          "inliers.max_slack": 0.6},
    "deficit >= 0.15 m, x1.5, cap 0.8 m": {"inliers.slack_min_deficit": 0.15, "inliers.partial_slack": 1.5,
                                           "inliers.max_slack": 0.8},
    "deficit >= 0.2 m, x1.5, cap 0.8 m": {"inliers.slack_min_deficit": 0.2, "inliers.partial_slack": 1.5,
                                          "inliers.max_slack": 0.8},
}


def main(scenes: list[str]) -> None:
    for scene in scenes:
        bench.ensure_map(scene, None)
        sequence = bench.cache_sequence(scene, None, None, lambda total: None)
        for alpha, descriptor in ((0.7, "fused"), (0.0, "SH")):
            for name, overrides in SETTINGS.items():
                variant = bench.Variant("slack", name, "clipclique", (*overrides.items(), ("similarity.alpha", alpha)))
                summary = bench.run_variant(sequence, variant, lambda: None)["summary"]
                print(f"{scene:15s} {descriptor:5s} {name:36s} top-1 {100 * summary['success@1']:5.1f} "
                      f"top-5 {100 * summary['success@5']:5.1f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["demo_apartment", "demo_desk", "demo", "demo_tum"])
