"""Fit the confidence model (P(pose within 1 m) per hypothesis) on scenes, measured on held-out scenes.

    .venv/bin/python tools/fit_confidence.py demo demo_tum                    # refit the shipped model
    .venv/bin/python tools/fit_confidence.py scene0002_00 fr2 --out my_confidence.json  # your own data

Each scene's frames go through the detector, the observation fit and the encoder once (as in
clipclique.benchmark.suite); all four methods then localize them. Held-out figures leave one scene out at a
time (the model scoring a scene never saw it): ECE, a reliability diagram and the share of frames
accepted at 95% precision. The model written to --out is then fitted on every scene, its Platt
calibration on leave-one-scene-out logits. Use a refitted model with
`clipclique-loc run SEQ --set confidence_model="my_confidence.json"`.
Output: --out (JSON; default the shipped clipclique/data/confidence.json) and --report
(default outputs/confidence/): reliability.png and held_out.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from clipclique.blas import one_blas_thread_by_default  # noqa: E402

for _variable, _value in (("HF_HUB_OFFLINE", "1"), ("YOLO_OFFLINE", "1")):
    os.environ.setdefault(_variable, _value)
one_blas_thread_by_default()  # before numpy loads, as the CLIs (clipclique.blas)


from clipclique.benchmark import calibration  # noqa: E402
from clipclique.benchmark.engine import ensure_map  # noqa: E402
from clipclique.benchmark.suite import cache_sequence  # noqa: E402
from clipclique.errors import ClipcliqueError  # noqa: E402
from clipclique.exits import user_errors  # noqa: E402
from clipclique.io.outputs import Staging  # noqa: E402
from clipclique.localization.results import json_safe  # noqa: E402
from clipclique.verify import confidence  # noqa: E402


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequences", nargs="+", help="scenes to fit on (two or more: one is held out at a time)")
    parser.add_argument("--frames", type=int, help="frames per scene, spread evenly [default: all]")
    parser.add_argument("--data-root", type=Path, help="datasets folder [default: $CLIPCLIQUE_DATA or ./data]")
    parser.add_argument("--out", type=Path, default=confidence.shipped_model_path(), help="model JSON to write")
    parser.add_argument("--report", type=Path, default=Path("outputs/confidence"), help="folder for the diagram")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    with user_errors("fit_confidence"):
        fit(args)


def fit(args: argparse.Namespace) -> None:
    if len(set(args.sequences)) < 2:
        raise ClipcliqueError("give two scenes or more: the model is measured on a scene it was not fitted on")
    names = list(dict.fromkeys(args.sequences))
    for name in names:  # every map first: a missing one stops the run before any work
        ensure_map(name, args.data_root)
    sequences = []
    for name in names:
        print(f"{name}: detect, fit, embed", file=sys.stderr)
        sequences.append(cache_sequence(name, args.data_root, args.frames, lambda total: None))
    rows = calibration.collect(sequences)
    measured = calibration.measure(rows, calibration.held_out(rows))
    args.report.mkdir(parents=True, exist_ok=True)
    calibration.plot_reliability(measured["reliability"], "Confidence on held-out scenes",
                                 args.report / "reliability.png")
    provenance = {"command": " ".join(["tools/fit_confidence.py", *sys.argv[1:]]),
                  "scenes": {s.name: len(s.frames) for s in sequences}, "hypotheses": len(rows),
                  "correct": int(rows.correct.sum()),
                  "held_out": {key: measured[key] for key in ("ece", "ece_answers", "acceptance")}}
    model = confidence.fit(rows.features, rows.correct, rows.scene, provenance=json_safe(provenance))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with Staging() as staging:  # the model and its held-out measurement replace the old ones together
        staging.path(args.report / "held_out.json").write_text(json.dumps(json_safe(measured), indent=1,
                                                                          allow_nan=False))
        staging.path(args.out).write_text(json.dumps(json_safe(model.to_json()), indent=1, allow_nan=False) + "\n")
        staging.commit()
    accepted = measured["acceptance"]
    print(f"held out: ECE {measured['ece']:.3f} (hypotheses), {measured['ece_answers']:.3f} (each frame's answer); "
          f"at 95% precision {accepted['accepted_correct']} of {accepted['frames_with_correct']} frames with a correct "
          f"hypothesis accepted ({100 * accepted['share_of_reachable']:.1f}%, threshold {accepted['threshold']})")
    print(f"model: {args.out}; diagram: {args.report / 'reliability.png'}")
    print("coefficients: " + ", ".join(f"{n} {c:+.2f}" for n, c in zip(model.features, model.coefficients))
          + f"; platt {model.platt[0]:.2f}, {model.platt[1]:+.2f}")


if __name__ == "__main__":
    main()
