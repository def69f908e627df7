"""Per-frame timings of clipclique-loc on a sequence: the algorithm (matching + inliers + pose) apart
from the detector, the observation fit and the encoder, and the whole frame without the detector.

    .venv/bin/python tools/bench_loc.py [SEQUENCE] [--method clipclique] [--repeat 3] [--set KEY=VALUE ...]

The map must exist (`clipclique-map build SEQUENCE`). Each frame's observations are localized
`--repeat` times and the fastest kept, which damps the noise of a shared machine; the table
gives medians and 90th percentiles over frames.
"""

from __future__ import annotations

import argparse
import os

from clipclique.blas import one_blas_thread_by_default  # noqa: E402

one_blas_thread_by_default()  # as clipclique-loc runs, before numpy loads (clipclique.blas)

import numpy as np  # noqa: E402

from clipclique.config import METHOD_PRESETS  # noqa: E402
from clipclique.exits import user_errors  # noqa: E402
from clipclique.localization.run import RunSettings, observe, prepare, selected_frames  # noqa: E402
from clipclique.outcomes import ALGORITHM_STAGES, PIPELINE_STAGES, QUERY_STAGES  # noqa: E402
from clipclique.pipeline import index_map, localize  # noqa: E402


def positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence", nargs="?", default="demo")
    parser.add_argument("--method", default="clipclique", choices=list(METHOD_PRESETS))
    parser.add_argument("--repeat", type=positive, default=3)
    parser.add_argument("--max-frames", type=positive, default=None)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="config override, e.g. inliers.verification=centers (repeatable)")
    args = parser.parse_args()

    with user_errors("bench_loc"):  # a missing map or sequence: one line, as clipclique-loc says it
        run = prepare(RunSettings(args.sequence, args.method, overrides=args.set, max_frames=args.max_frames,
                                  record=False))
    index = index_map(run.map, run.config)
    rows: dict[str, list[float]] = {stage: []
                                    for stage in (*QUERY_STAGES, *PIPELINE_STAGES, "algorithm", "no detector")}
    for i in selected_frames(run):
        seen = observe(run, run.sequence[i])
        results = [localize(seen.observations, index, run.config) for _ in range(args.repeat)]
        fastest = min(results, key=lambda r: sum(r.timings[s] for s in ALGORITHM_STAGES))
        for stage, seconds in (seen.timings | fastest.timings).items():
            rows[stage].append(1e3 * seconds)
        rows["algorithm"].append(1e3 * sum(fastest.timings[s] for s in ALGORITHM_STAGES))
        rows["no detector"].append(1e3 * (sum(seen.timings.values()) - seen.timings["detector"]
                                          + sum(fastest.timings.values())))

    print(f"{args.method} on {args.sequence}: {len(rows['algorithm'])} frames, {os.cpu_count()} cores "
          "(a shared machine gives noisy timings)")
    print(f"detector: {run.detector.name}; encoder: {run.encoder.name if run.encoder else 'none'}")
    print(f"{'stage':<14}{'median ms':>10}{'p90 ms':>10}")
    for stage, times in rows.items():
        print(f"{stage:<14}{np.median(times):>10.2f}{np.percentile(times, 90):>10.2f}")
    print(f"algorithm = matching + inliers + pose, fastest of {args.repeat}; target: median <= 10 ms")
    print("no detector = the whole frame but the detector: observations + encoder + every localization stage")


if __name__ == "__main__":
    main()
