"""The weighted pose fits a query cannot skip, and their share of its time: the floor under issue 20's 1 ms.

    .venv/bin/python tools/bench_fits.py [SCENE ...] [--max-frames 30] [--repeat 3]

Every pose a query computes is a weighted fit of a correspondence set, one compiled pass per batch
(clipclique.pose.fit: the moments, both covariances' eigenvalues and Horn's quaternion). Each query runs
once with its fits recorded (the refinement round by round, which computes the same as its one compiled
call: tests/unit/pose/test_refine.py), then, fastest of `--repeat`, the whole `localize`
and the recorded batches fitted again alone, the same calls (`fit_sets` for the clique poses, the weighted sets
gathered and fitted, `fit_rigid_batch` for the refinement's, each a Python call that the refinement's own compiled
call does without). Printed per scene, medians over frames: the sets fitted per query, ms of the fits
and of the whole query, and the fits' share of it.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

from clipclique.blas import one_blas_thread_by_default

one_blas_thread_by_default()  # as clipclique-loc runs, before numpy loads (clipclique.blas)

import numpy as np  # noqa: E402
from bench_speed import fastest  # noqa: E402  (this directory's: ms of the fastest of `repeat` calls)

import clipclique.inliers.hypotheses as hypotheses  # noqa: E402  (the clique poses' fits)
import clipclique.pipeline as pipeline  # noqa: E402
import clipclique.pose.refine as refine  # noqa: E402
from clipclique.localization.run import RunSettings, observe, prepare, selected_frames  # noqa: E402
from clipclique.pose.fit import fit_rigid_batch, fit_sets  # noqa: E402

Batch = tuple[Callable, tuple, int]  # the fit called, its arguments, the sets it fits


def recorded_fits(query: Callable[[], object]) -> list[Batch]:
    """The fit batches one call of `query` makes, in order, with their inputs copied."""
    batches: list[Batch] = []

    def recording(fit: Callable, sets: Callable[[tuple], int]) -> Callable:
        def recorded(*arguments):
            copied = tuple(np.array(a) if isinstance(a, np.ndarray) else a for a in arguments)
            batches.append((fit, copied, sets(copied)))
            return fit(*arguments)
        return recorded

    saved = hypotheses.fit_sets, refine.fit_rigid_batch, refine.refine_stack
    hypotheses.fit_sets = recording(fit_sets, lambda arguments: len(arguments[2]))  # (pairs, scores, counts, ...)
    refine.fit_rigid_batch = recording(fit_rigid_batch, lambda arguments: len(arguments[2]))  # (source, target, w)
    refine.refine_stack = lambda stack, observations, map, similarity, radius, weights, rounds=2, landmarks=None: (
        refine._refine_by_rounds(stack, observations, map, similarity, radius, weights, rounds, landmarks))
    try:
        query()
    finally:
        hypotheses.fit_sets, refine.fit_rigid_batch, refine.refine_stack = saved
    return batches


def measure(scene: str, max_frames: int, repeat: int) -> None:
    run = prepare(RunSettings(scene, max_frames=max_frames, record=False))
    index = pipeline.index_map(run.map, run.config)
    queries = [observe(run, run.sequence[i]).observations for i in selected_frames(run)]
    clique_sets, refined_sets, fits, whole = [], [], [], []
    for observations in queries:
        def query(observations=observations) -> object:
            return pipeline.localize(observations, index, run.config)
        query()  # compiled and warm
        batches = recorded_fits(query)
        clique_sets.append(sum(sets for fit, _, sets in batches if fit is fit_sets))
        refined_sets.append(sum(sets for fit, _, sets in batches if fit is fit_rigid_batch))

        def refit(batches=batches) -> None:
            for fit, arguments, _ in batches:
                fit(*arguments)
        fits.append(fastest(refit, repeat))
        whole.append(fastest(query, repeat))
    fit_ms, whole_ms = np.median(fits), np.median(whole)
    share = np.median(np.array(fits) / np.array(whole))
    print(f"{scene}: {len(queries)} frames; sets fitted per query, median: {np.median(clique_sets):.0f} clique poses "
          f"(with their conditioning), {np.median(refined_sets):.0f} refinement; fits alone "
          f"{fit_ms:.2f} ms, whole localize {whole_ms:.2f} ms, the fits' share {100 * share:.0f}%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", default=["demo", "demo_desk", "demo_apartment"])
    parser.add_argument("--max-frames", type=int, default=30)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    for scene in args.scenes:
        measure(scene, args.max_frames, args.repeat)


if __name__ == "__main__":
    main()
