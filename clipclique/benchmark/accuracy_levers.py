"""Accuracy levers side by side: each a config key, on the same cached observations of every realistic scene.

    .venv/bin/python -m clipclique.benchmark.accuracy_levers       # every lever, both descriptors, all scenes
    .venv/bin/python -m clipclique.benchmark.accuracy_levers --scenes demo_clutter --frames 40 \
        --levers before "defaults (after)"
    .venv/bin/python -m clipclique.benchmark.accuracy_levers --reference  # with the paper preset, the literal reference
    .venv/bin/python -m clipclique.benchmark.accuracy_levers --timing     # with the verification stage's median ms
    .venv/bin/python -m clipclique.benchmark.accuracy_levers --scenes demo_sparse --view sparse --candidates
        # only the frames of 3-5 mapped objects (suite.view_of), with what the candidates lack there

Each scene's frames go through the detector, the observation fit and the (simulated) CLIP once
(clipclique.benchmark.suite's cache); every lever then localizes those observations, once with Semantic
Histograms only (`similarity.alpha=0`) and once fused with the simulated CLIP. Printed as a
markdown table: top-1 success within each of metrics.SUCCESS_THRESHOLDS_M, and top-5 within 1 m (what re-ranking
could reach), per scene, descriptor and lever; with --timing also the median per frame of the verification stage
(`LocalizationResult.timings`, which holds the box refinement too), one pass: on a shared machine compare rows
run together. `--view sparse` (busy, few) scores only the frames whose observations are 3-5 distinct mapped objects
(more, fewer: `suite.view_of`, issue 37's sparse views), after --frames spreads its frames; `--candidates` adds,
per lever, the frames whose initial candidates hold fewer than 3 right pairs (observation, its own landmark: no
pose can rest on right pairs alone) and the share of mapped observations whose landmark is not among their
candidates (the literal reference has no candidates: "-"); `--changed-from LEVER` the frames whose top-1 error moves
by more than CHANGED_M (or gains or loses its pose) against that lever's: whether a lever acts at all.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from clipclique.benchmark import suite
from clipclique.config import make_config
from clipclique.metrics import SUCCESS_THRESHOLDS_M, evaluate_frame, success_within
from clipclique.outcomes import LocalizationResult, Stage
from clipclique.pipeline import index_map, localize

SCENES = ("demo_apartment", "demo_desk", "demo_clutter", "demo", "demo_tum", "demo_sparse")
DESCRIPTORS = {"SH": {"similarity.alpha": 0.0}, "CLIP": {}}
CHANGED_M = 0.01  # --changed-from: a frame whose top-1 error moves by more than this is changed

# Lever name -> config overrides on top of the defaults. "before" is every kept lever off (the
# defaults before tools/accuracy_levers.py measured them); each "no ..." turns one kept lever off.
# "previous" is the second round's starting point (re-ranking the five heaviest cliques, every missed
# landmark costing in full); "pool only" and "sized misses only" add one of its two kept levers. The third
# round's starting point is "no missed share" (each missed landmark costing alike however many the pose expects).
# The look-alike candidates (the third round's matching lever) are off in "previous" and "before";
# "no look-alike candidates" is today's without them. The box refinement (issue 37, off by default): "box
# refinement" turns it on with its other keys' defaults; the other "box refinement" rows change one of them.
PREVIOUS = {"inliers.rerank_pool": 5, "verification.missed_full_area": 0.0, "verification.missed_share_from": 0.0,
            "matching.lookalike_candidates": 0, "pose.box_refine_steps": 0}
BEFORE = {"inliers.rerank": "none", "inliers.duplicate_iou": 0.0, "pose.refine_radius": 0.0} | PREVIOUS
LEVERS: dict[str, dict[str, Any]] = {
    "before": BEFORE,
    "rerank only": BEFORE | {"inliers.rerank": "verification"},
    "refine only": BEFORE | {"pose.refine_radius": 0.3},
    "duplicates only": BEFORE | {"inliers.duplicate_iou": 0.7},
    "previous": PREVIOUS,
    "pool only": PREVIOUS | {"inliers.rerank_pool": 50},
    "sized misses only": PREVIOUS | {"verification.missed_full_area": 0.0625},
    "defaults (after)": {},
    "no refine": {"pose.refine_radius": 0.0},
    "no duplicates": {"inliers.duplicate_iou": 0.0},
    "no missed penalty": {"verification.missed_weight": 0.0},
    "rerank confidence": {"inliers.rerank": "confidence"},
    "no missed share": {"verification.missed_share_from": 0.0},
    "no look-alike candidates": {"matching.lookalike_candidates": 0},
    "look-alike candidates 1": {"matching.lookalike_candidates": 1},
    "look-alike candidates 3": {"matching.lookalike_candidates": 3},
    "look-alike candidates, any size": {"matching.lookalike_size_ratio": 1000.0},
    # issue 37: the kept hypotheses' poses aligned with the detection boxes (clipclique.verify.boxalign)
    "box refinement": {"pose.box_refine_steps": 3},
    "box refinement 5 steps": {"pose.box_refine_steps": 5},
    "box refinement, boxes alone": {"pose.box_refine_steps": 5, "pose.box_refine_centre_m": 0.0,
                                    "pose.box_refine_relative": 0.0},
    "box refinement, no centre prior": {"pose.box_refine_steps": 3, "pose.box_refine_centre_m": 0.0},
    "box refinement, centres 2 cm": {"pose.box_refine_steps": 3, "pose.box_refine_centre_m": 0.02},
    "box refinement, centres 10 cm": {"pose.box_refine_steps": 3, "pose.box_refine_centre_m": 0.1},
    "box refinement, pixels alone": {"pose.box_refine_steps": 3, "pose.box_refine_relative": 0.0},
    "box refinement, 10 px": {"pose.box_refine_steps": 3, "pose.box_refine_scale": 10.0},
    "box refinement, size 0.3": {"pose.box_refine_steps": 3, "pose.box_refine_size_weight": 0.3},
}


@dataclass
class Missing:
    """What the initial candidates lack, summed over frames (`--candidates`)."""

    frames: int = 0  # frames scored
    short_frames: int = 0  # ... whose candidates hold fewer than 3 right pairs
    mapped: int = 0  # observations of a mapped object
    unmatched: int = 0  # ... whose own landmark is not among their candidates

    def add(self, result: LocalizationResult, right: np.ndarray) -> None:
        """One frame: `right` the (K, N) mapped pairs of its observations (suite.mapped_pairs)."""
        pairs = result.candidates.reshape(-1, 2)
        hit = right[pairs[:, 0], pairs[:, 1]] if len(pairs) else np.zeros(0, bool)
        found = np.unique(pairs[hit, 0])
        self.frames += 1
        self.short_frames += len(found) < 3
        self.mapped += int(right.any(axis=1).sum())
        self.unmatched += int(right.any(axis=1).sum()) - len(found)

    def cells(self) -> str:
        return f" {self.short_frames} of {self.frames} | {self.unmatched / max(self.mapped, 1):.1%} |"


def top1_errors(sequence: suite.CachedSequence, method: str, overrides: dict[str, Any],
                reference: bool = False, laps: list[float] | None = None,
                missing: Missing | None = None) -> tuple[list[float | None], float]:
    """Top-1 translation error per frame (None when no pose), and top-5 success within 1 m; `laps`: each frame's
    verification seconds appended (the literal reference has none: NaN); `missing`: each frame's candidates
    added."""
    config = make_config(method, overrides=overrides)
    localizer = (partial(suite.literal_localize, map=sequence.map, alpha=config.similarity.alpha) if reference
                 else partial(localize, index=index_map(sequence.map, config), config=config))
    errors, top5 = [], []
    for frame in sequence.frames:
        result = localizer(frame.observations)
        if laps is not None:
            laps.append(result.timings.get(Stage.VERIFICATION, float("nan")))
        if missing is not None:
            missing.add(result, suite.mapped_pairs(frame.observations, sequence.map))
        evaluation = evaluate_frame(result, frame.observations, sequence.map, frame.gt_pose, config, frame.index)
        errors.append(evaluation.translation_error)
        top5.append(evaluation.success[5])
    return errors, float(np.mean(top5))


def changed(errors: list[float | None], base: list[float | None]) -> int:
    """Frames whose top-1 error moves by more than CHANGED_M against `base`'s, or that gain or lose a pose."""
    return sum((a is None) != (b is None) or (a is not None and b is not None and abs(a - b) > CHANGED_M)
               for a, b in zip(errors, base))


def row(scene: str, descriptor: str, lever: str, errors: list[float | None], top5: float,
        laps: list[float] | None = None, missing: Missing | None = None, reference: bool = False) -> str:
    within = " | ".join(f"{share:.1%}" for share in success_within(errors).values())
    timing = "" if laps is None else f" {1e3 * float(np.median(laps)):.3f} |"
    lacking = "" if missing is None else " - | - |" if reference else missing.cells()
    return f"| {scene} | {descriptor} | {lever} | {within} | {top5:.1%} |{timing}{lacking}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--levers", nargs="+", default=list(LEVERS), choices=list(LEVERS))
    parser.add_argument("--frames", type=int, help="frames per scene, spread evenly [default: all]")
    parser.add_argument("--reference", action="store_true", help="also the paper preset and the literal reference")
    parser.add_argument("--timing", action="store_true", help="also the verification stage's median ms per frame")
    parser.add_argument("--view", choices=suite.VIEWS, default="all",
                        help="score only the frames of this view: sparse 3-5 distinct mapped objects observed, busy "
                             "more, few fewer (suite.view_of) [default: all]")
    parser.add_argument("--candidates", action="store_true",
                        help="also what the initial candidates lack: frames with fewer than 3 right pairs, and "
                             "the mapped observations without their landmark among their candidates")
    parser.add_argument("--changed-from", choices=list(LEVERS), metavar="LEVER",
                        help="also the frames each row changes against this lever's (top-1 error, CHANGED_M)")
    args = parser.parse_args(argv)
    within = "top-1 within " + " | ".join(f"{t:g} m" for t in SUCCESS_THRESHOLDS_M)
    timing = " verification ms |" if args.timing else ""
    lacking = " frames < 3 right candidates | mapped observations without their landmark |" if args.candidates else ""
    moved = f" frames changed from {args.changed_from} |" if args.changed_from else ""
    print(f"| scene | descriptor | lever | {within} | top-5 within 1 m |{timing}{lacking}{moved}")
    print("|---|---|---|" + "---|" * (len(SUCCESS_THRESHOLDS_M) + 1 + args.timing + 2 * args.candidates
                                     + bool(args.changed_from)), flush=True)
    for scene in args.scenes:
        suite.ensure_map(scene, None)
        sequence = suite.in_view(suite.cache_sequence(scene, None, args.frames, lambda total: None), args.view)
        if args.view != "all":
            print(f"{scene}: {len(sequence.frames)} frames of view {args.view}", file=sys.stderr, flush=True)
        if not sequence.frames:
            continue
        for descriptor, base in DESCRIPTORS.items():
            if descriptor == "CLIP" and not sequence.has_clip:
                continue
            rows = [(lever, "clipclique", base | LEVERS[lever], False) for lever in args.levers]
            if args.reference:
                rows += [("paper preset", "clipclique-paper", base, False),
                         ("literal reference", "clipclique-paper", base, True)]
            base = (top1_errors(sequence, "clipclique", base | LEVERS[args.changed_from])[0] if args.changed_from
                    else None)
            for lever, method, overrides, reference in rows:
                laps = [] if args.timing else None
                missing = Missing() if args.candidates else None
                errors, top5 = top1_errors(sequence, method, overrides, reference, laps, missing)
                line = row(scene, descriptor, lever, errors, top5, laps, missing, reference)
                print(line + ("" if base is None else f" {changed(errors, base)} |"), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
