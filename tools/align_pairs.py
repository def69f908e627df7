"""Map-to-map alignment on generated pairs made the way real ones differ (issue 38): how often a wrong answer is
confident and how often a right one is refused.

    .venv/bin/python tools/align_pairs.py --first 30000 --count 300      # every vocabulary
    .venv/bin/python tools/align_pairs.py --first 20000 --count 120 --vocabulary generic

Each seed is one room mapped by two simulated detectors (clipclique.sim.mappairs.detector_pair: their own misses,
false positives and confusions, one with a coarser vocabulary, sparse overlap), in each vocabulary asked for
(generic class names, COCO names on both sides, or the query map in LVIS names). An answer is the best candidate
of an alignment that is not ambiguous; it is right when every query landmark lands within TOLERANCE_M of where
the truth puts it and the rotation is within TOLERANCE_DEG (clipclique.multiframe.mapalign), and confident at
0.5 or more. Printed per vocabulary: answers, wrong ones that are confident (with their seeds), right ones
refused, ambiguous alignments, and seeds without a transform.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from clipclique.config import make_config
from clipclique.multiframe import mapalign
from clipclique.pipeline import align_maps
from clipclique.pose.distance import rotation_angle
from clipclique.sim.mappairs import VOCABULARIES, detector_pair


def summary(seeds: range, vocabulary: str) -> str:
    """One vocabulary's line (module docstring)."""
    config = make_config("clipclique")
    confident_wrong, wrong, refused, right, ambiguous, none = [], 0, 0, 0, 0, 0
    for seed in seeds:
        query, map, truth = detector_pair(np.random.default_rng(seed), vocabulary)
        alignment = align_maps(query, map, config)
        if not alignment.candidates:
            none += 1
            continue
        if alignment.ambiguous:
            ambiguous += 1
            continue
        best = alignment.candidates[0]
        centers = query.ellipsoids.centers
        off_m = float(np.linalg.norm(best.pose.apply(centers) - truth.apply(centers), axis=1).max())
        off_deg = math.degrees(rotation_angle(best.pose.rotation.T @ truth.rotation))
        if off_m < mapalign.TOLERANCE_M and off_deg < mapalign.TOLERANCE_DEG:
            right += 1
            refused += best.confidence < 0.5
        else:
            wrong += 1
            if best.confidence >= 0.5:
                confident_wrong.append(f"{seed} ({len(best.correspondences)} correspondences, "
                                       f"{best.confidence:.2f}, {off_m:.2f} m, {off_deg:.1f} deg)")
    share = f"{100 * refused / right:.0f}%" if right else "-"
    return (f"{vocabulary}: seeds {seeds.start}-{seeds.stop - 1}, {wrong + right} answers; wrong above 0.5: "
            f"{len(confident_wrong)} of {wrong} wrong{': ' if confident_wrong else ''}{', '.join(confident_wrong)}; "
            f"right refused: {refused} of {right} ({share}); ambiguous {ambiguous}; no transform {none}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--first", type=int, default=30_000, help="first seed")
    parser.add_argument("--count", type=int, default=300, help="seeds")
    parser.add_argument("--vocabulary", choices=VOCABULARIES, action="append",
                        help="class names (repeatable; default: every one)")
    args = parser.parse_args()
    for vocabulary in args.vocabulary or VOCABULARIES:
        print(summary(range(args.first, args.first + args.count), vocabulary))


if __name__ == "__main__":
    main()
