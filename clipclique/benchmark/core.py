"""Speed of the core algorithm on synthetic maps (everything here is simulated data).

    .venv/bin/python tools/bench_core.py                 # all parts, default sizes
    .venv/bin/python tools/bench_core.py --desk-counts 47 470 4700 --desk-frames 10 --json out.json
    /usr/bin/time -v .venv/bin/python tools/bench_core.py --degenerate 5000   # peak memory, worst case
    .venv/bin/python tools/bench_core.py --literal 47 94   # beside the literal networkx reference

Part 1: matching + inliers + pose for one query against a 50-landmark map, median ms per method.
Part 2: the hard case: a simulated desk scene with the statistics of a real desk object map
(`desk_map`, REAL_SCENES.md: 47 objects, 19 classes, about 25 observations and 80 candidates per
query, thousands of maximal cliques), copied into rooms 20 m apart, SH only. The pipeline's
branch-and-bound search beside the previous implementation (igraph full enumeration + Python
ranking, `previous_solve`) on the same queries, their ratio, cap hits and growth exponents.
Part 3: scalability on the demo-like synthetic rooms (about 2 maximal cliques per query), as the
paper measures it, with the growth exponent (slope of a log-log least-squares line).
`scalability()` is importable for other benchmark scripts.
`--literal COUNTS`: only the whole query (descriptors to pose) on the desk scene, the project
beside `clipclique/benchmark/literal_reference.py` (networkx, no caps) on the same queries, SH only.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from clipclique.benchmark import literal_reference
from clipclique.config import METHOD_PRESETS, LocalizationConfig, make_config
from clipclique.inliers.compatibility import compatibility_graph
from clipclique.inliers.reference_cliques import maximal_cliques
from clipclique.outcomes import ALGORITHM_STAGES
from clipclique.pipeline import LocalizationResult, MapIndex, index_map, localize
from clipclique.pose.fit import DegeneratePoseError, correspondence_weights, fit_rigid
from clipclique.sim.poses import random_rotation
from clipclique.sim.synthetic import duplicate_rooms, synthetic_map, synthetic_query
from clipclique.types import Ellipsoids, Map, Observations, Pose


def single_query(method: str, landmarks: int = 50, frames: int = 50, seed: int = 0) -> dict:
    """Median and 90th-percentile ms of matching + inliers + pose (and of the full query) for `method`."""
    config = make_config(method)
    rng = np.random.default_rng(seed)
    map = synthetic_map(rng, num_landmarks=landmarks)
    index = index_map(map, config)
    algorithm, total = [], []
    for _ in range(frames):
        observations, _ = synthetic_query(map, rng)
        timings = localize(observations, index, config).timings
        algorithm.append(1e3 * sum(timings[s] for s in ALGORITHM_STAGES))
        total.append(1e3 * sum(timings.values()))
    return {
        "method": method,
        "landmarks": landmarks,
        "median_ms": float(np.median(algorithm)),
        "p90_ms": float(np.percentile(algorithm, 90)),
        "median_total_ms": float(np.median(total)),
    }


def scalability(
    counts: list[int], method: str = "clipclique", room: int = 50, frames: int = 10, seed: int = 0
) -> list[dict]:
    """Per landmark count: a `room`-landmark map duplicated count // room times, `frames` queries
    from it; median ms of matching + inliers + pose and of the whole query, candidates, cliques."""
    rows = []
    for count in counts:
        algorithm, total, candidates, cliques, caps = [], [], [], [], 0
        for map, _, _, result in duplicated_room_queries(count, method, room, frames, seed):
            algorithm.append(1e3 * sum(result.timings[s] for s in ALGORITHM_STAGES))
            total.append(1e3 * sum(result.timings.values()))
            candidates.append(len(result.candidates))
            cliques.append(result.num_cliques)
            caps += result.cap_hit is not None
        rows.append(
            {
                "method": method,
                "landmarks": len(map),
                "median_ms": float(np.median(algorithm)),
                "median_total_ms": float(np.median(total)),
                "candidates": float(np.median(candidates)),
                "cliques": float(np.median(cliques)),
                "cap_hits": caps,
            }
        )
    return rows


def duplicated_room_queries(
    count: int, method: str, room: int, frames: int, seed: int
) -> Iterator[tuple[Map, Observations, LocalizationConfig, LocalizationResult]]:
    """`frames` localized queries of room 0 against `count // room` identical rooms side by side."""
    config = make_config(method)
    base = synthetic_map(np.random.default_rng(seed), num_landmarks=room)
    map = duplicate_rooms(base, max(1, count // room))
    index = index_map(map, config)
    rng = np.random.default_rng(seed + 1)
    for _ in range(frames):
        observations, _ = synthetic_query(base, rng)  # every room looks the same
        yield map, observations, config, localize(observations, index, config)


def growth_exponent(rows: list[dict], key: str = "median_ms") -> float:
    """Slope of log(latency) against log(landmarks): 1 = linear, 2 = quadratic."""
    x = np.log([r["landmarks"] for r in rows])
    y = np.log([max(r[key], 1e-6) for r in rows])
    return float(np.polyfit(x, y, 1)[0])


DESK_CLASS_COUNTS = (8, 7, 4, 3, 3, 3, 3, 2, 2, 2, 2) + (1,) * 8  # 47 objects, 19 classes (REAL_SCENES.md)
DESKS = np.array([[1.5, 1.2, 0.75], [3.6, 2.0, 0.75]])  # two desks in a 5.5 x 3.4 x 1 m office
ROOM_SPACING = 20.0  # metres between copies of the desk scene


def desk_map(rng: np.random.Generator) -> Map:
    """A simulated desk object map with REAL_SCENES.md's statistics: 47 objects of 19 classes
    (8 cups, 7 books, ...), most crowded on two desks (degree within 0.8 m 0 to about 23,
    median about 17), 12% anywhere in the room."""
    class_ids = np.repeat(np.arange(len(DESK_CLASS_COUNTS)), DESK_CLASS_COUNTS)
    count = len(class_ids)
    centers = DESKS[rng.integers(0, len(DESKS), count)] + rng.uniform(-1, 1, (count, 3)) * [0.6, 0.4, 0.2]
    loose = rng.random(count) < 0.12
    centers[loose] = rng.uniform(0, 1, (loose.sum(), 3)) * [5.5, 3.4, 1.0]
    names = [f"class{c}" for c in range(len(DESK_CLASS_COUNTS))]
    return Map(
        Ellipsoids(centers, rng.uniform(0.04, 0.2, (count, 3)), np.repeat(np.eye(3)[None], count, axis=0)),
        class_ids, names, [names[c] for c in class_ids], np.arange(count) + 1, provenance={"simulated": True},
    )


def desk_query(map: Map, rng: np.random.Generator, reach: float = 3.5, half_fov_deg: float = 40.0,
               noise: float = 0.08) -> Observations:
    """What a camera 1-2 m from a random object sees of the desk: every object within `reach`
    metres and `half_fov_deg` of its optical axis (about 25), centres with `noise` metres of noise."""
    centers = map.ellipsoids.centers
    target = centers[rng.integers(len(map))]
    heading = rng.uniform(0, 2 * np.pi)
    eye = target + np.array([np.cos(heading), np.sin(heading), 0.0]) * rng.uniform(1.0, 2.0) + [0, 0, 0.5]
    rays = centers - eye
    distance = np.linalg.norm(rays, axis=1)
    forward = (target - eye) / np.linalg.norm(target - eye)
    visible = np.flatnonzero((distance < reach) & (rays @ forward > np.cos(np.radians(half_fov_deg)) * distance))
    seen = map.ellipsoids.subset(visible).transformed(Pose(random_rotation(rng), eye).inverse())
    seen.centers = seen.centers + rng.normal(scale=noise, size=seen.centers.shape)
    return Observations(seen, map.class_ids[visible], None, map.instance_ids[visible], np.arange(len(visible)))


def previous_solve(observations: Observations, map: Map, result: LocalizationResult,
                   config: LocalizationConfig) -> tuple[float, int, str | None]:
    """The implementation before the branch-and-bound search, for comparison: igraph enumerates
    every maximal clique, Python sums and sorts them, one pose per clique until top_n.
    Returns (seconds, maximal cliques, cap)."""
    settings = config.inliers
    start = time.perf_counter()
    edges = compatibility_graph(observations.ellipsoids.centers, map.ellipsoids.centers, result.candidates,
                                settings.d_comp)
    cliques, cap = maximal_cliques(edges, len(result.candidates), settings.min_clique_size, settings.max_cliques,
                                   settings.time_limit_s)
    totals = np.array([result.candidate_scores[c].sum() for c in cliques])
    poses = 0
    for index in np.argsort(-totals, kind="stable"):
        pairs = result.candidates[cliques[index]]
        weights = correspondence_weights(result.candidate_scores[cliques[index]],
                                         observations.ellipsoids.axes[pairs[:, 0]],
                                         map.ellipsoids.axes[pairs[:, 1]], config.pose.weights)
        try:
            fit_rigid(observations.ellipsoids.centers[pairs[:, 0]], map.ellipsoids.centers[pairs[:, 1]], weights)
        except DegeneratePoseError:
            continue
        poses += 1
        if poses == config.top_n:
            break
    return time.perf_counter() - start, len(cliques), cap


def desk_rooms(counts: list[int],
               config: LocalizationConfig, seed: int) -> Iterator[tuple[Map, Map, MapIndex, np.random.Generator]]:
    """Per landmark count: the desk scene, its copies in rooms ROOM_SPACING apart, their index, and
    the generator of the queries (the same queries at every count)."""
    base = desk_map(np.random.default_rng(seed))
    for count in counts:
        map = duplicate_rooms(base, max(1, count // len(base)),
                              gap=ROOM_SPACING - np.ptp(base.ellipsoids.centers[:, 0]))
        yield base, map, index_map(map, config), np.random.default_rng(seed + 1)


def desk_scalability(counts: list[int], frames: int = 30, seed: int = 0) -> list[dict]:
    """Per landmark count: the desk scene copied into rooms ROOM_SPACING apart, `frames` queries
    of room 0, SH only; median ms of matching + inliers + pose now and with `previous_solve`."""
    config = make_config("clipclique", overrides={"similarity.descriptor": "sh"})
    rows = []
    for base, map, index, rng in desk_rooms(counts, config, seed):
        now, before, candidates, cliques, reached, caps, caps_before = [], [], [], [], [], 0, 0
        for _ in range(frames):
            observations = desk_query(base, rng)
            result = localize(observations, index, config)
            seconds, enumerated, cap = previous_solve(observations, map, result, config)
            now.append(1e3 * sum(result.timings[s] for s in ALGORITHM_STAGES))
            before.append(1e3 * (result.timings["matching"] + seconds))
            candidates.append(len(result.candidates))
            cliques.append(enumerated)
            reached.append(result.num_cliques)
            caps += result.cap_hit is not None
            caps_before += cap is not None
        rows.append({"landmarks": len(map), "median_ms": float(np.median(now)), "previous_ms": float(np.median(before)),
                     "candidates": float(np.median(candidates)), "cliques": float(np.median(cliques)),
                     "max_cliques": int(np.max(cliques)), "reached": float(np.median(reached)),
                     "cap_hits": caps, "previous_cap_hits": caps_before})
    return rows


def literal_comparison(counts: list[int], frames: int = 10, seed: int = 0) -> list[dict]:
    """Per landmark count: median ms of a whole SH-only query (descriptors to pose) on the desk
    scene, the project (map indexed once, as a user's run does) beside the literal reference."""
    config = make_config("clipclique-paper", overrides={"similarity.alpha": 0.0})
    rows = []
    for base, map, index, rng in desk_rooms(counts, config, seed):
        project, literal = [], []
        for _ in range(frames):
            observations = desk_query(base, rng)
            start = time.perf_counter()
            localize(observations, index, config)
            project.append(1e3 * (time.perf_counter() - start))
            start = time.perf_counter()
            literal_reference.localize(observations, map, alpha=0.0)
            literal.append(1e3 * (time.perf_counter() - start))
        rows.append({"landmarks": len(map), "project_ms": float(np.median(project)),
                     "literal_ms": float(np.median(literal))})
    return rows


def degenerate(count: int) -> LocalizationResult:
    """One query against `count` identical overlapping landmarks of one class: the worst case for
    memory (every candidate pair within reach). The caps must keep it bounded; says which one hit.
    CLIP similarity: the figure is the matching and clique stages' (the semantic graph has its own bound)."""
    config = make_config("clipclique", overrides={"similarity.descriptor": "clip"})
    rng = np.random.default_rng(0)
    base = synthetic_map(rng, num_landmarks=1, num_classes=1)
    map = duplicate_rooms(base, count, gap=-np.ptp(base.ellipsoids.centers[:, 0]))  # all at one spot
    observations, _ = synthetic_query(synthetic_map(rng, num_landmarks=12, num_classes=1), rng, num_visible=12,
                                      num_outliers=0)
    return localize(observations, index_map(map, config), config)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", type=int, nargs="+", default=[50, 100, 200, 500, 1000, 2000, 5000])
    parser.add_argument("--desk-counts", type=int, nargs="+", default=[47, 94, 235, 470, 940, 2350, 4700])
    parser.add_argument("--frames", type=int, default=10, help="queries per landmark count (demo-like map)")
    parser.add_argument("--desk-frames", type=int, default=30, help="queries per landmark count (desk scene)")
    parser.add_argument("--method", default="clipclique", choices=list(METHOD_PRESETS))
    parser.add_argument("--json", type=Path, help="also write the tables here (scalability plot data)")
    parser.add_argument("--plot", type=Path, help="also draw the scalability plot here (PNG)")
    parser.add_argument("--degenerate", type=int, metavar="N",
                        help="only localize one query against N identical overlapping landmarks (peak memory: run "
                             "under /usr/bin/time -v)")
    parser.add_argument("--literal", type=int, nargs="+", metavar="COUNT",
                        help="only compare whole desk queries with clipclique/benchmark/literal_reference.py at these "
                             "landmark counts")
    args = parser.parse_args()
    if args.literal:
        print(f"whole query on the desk scene, SH only, {args.desk_frames} queries each (median ms)")
        print(f"{'landmarks':>10}{'project':>10}{'literal':>10}{'ratio':>8}")
        for row in literal_comparison(args.literal, args.desk_frames):
            print(f"{row['landmarks']:>10}{row['project_ms']:>10.1f}{row['literal_ms']:>10.0f}"
                  f"{row['literal_ms'] / row['project_ms']:>8.1f}")
        return
    if args.degenerate:
        start = time.perf_counter()
        result = degenerate(args.degenerate)
        print(f"{args.degenerate} identical landmarks: {len(result.candidates)} candidates, cap hit: {result.cap_hit}, "
              f"{1e3 * (time.perf_counter() - start):.0f} ms with the map index "
              f"({1e3 * (result.timings['matching'] + result.timings['inliers']):.0f} ms matching + inliers), "
              f"failure: {result.failure}")
        return

    print("Part 1: one query vs a 50-landmark synthetic map (matching + inliers + pose)")
    print(f"{'method':<12}{'median ms':>10}{'p90 ms':>10}{'total ms':>10}")
    for method in METHOD_PRESETS:
        row = single_query(method)
        print(f"{method:<12}{row['median_ms']:>10.2f}{row['p90_ms']:>10.2f}{row['median_total_ms']:>10.2f}")

    print(f"\nPart 2: simulated desk scene (47 objects) copied into rooms {ROOM_SPACING:.0f} m apart, SH only, "
          f"{args.desk_frames} queries each; median ms of matching + inliers + pose")
    desk = desk_scalability(args.desk_counts, args.desk_frames)
    print(f"{'landmarks':>10}{'now ms':>9}{'before ms':>10}{'ratio':>7}{'cands':>7}{'cliques':>9}{'max':>8}"
          f"{'reached':>9}{'caps':>6}{'caps before':>12}")
    for row in desk:
        print(f"{row['landmarks']:>10}{row['median_ms']:>9.2f}{row['previous_ms']:>10.1f}"
              f"{row['previous_ms'] / row['median_ms']:>7.1f}{row['candidates']:>7.0f}{row['cliques']:>9.0f}"
              f"{row['max_cliques']:>8}{row['reached']:>9.0f}{row['cap_hits']:>6}{row['previous_cap_hits']:>12}")
    print(f"growth exponent (log-log slope): now {growth_exponent(desk):.2f}, "
          f"before {growth_exponent(desk, 'previous_ms'):.2f}")

    print(f"\nPart 3: scalability, {args.method}, demo-like synthetic rooms of 50 landmarks side by side")
    rows = scalability(args.counts, args.method, frames=args.frames)
    print(f"{'landmarks':>10}{'median ms':>11}{'total ms':>10}{'candidates':>11}{'cliques':>9}{'caps':>6}")
    for row in rows:
        print(
            f"{row['landmarks']:>10}{row['median_ms']:>11.2f}{row['median_total_ms']:>10.2f}"
            f"{row['candidates']:>11.0f}{row['cliques']:>9.0f}{row['cap_hits']:>6}"
        )
    tail = rows[-3:]
    print(
        f"growth exponent (log-log slope): {growth_exponent(rows):.2f} over all counts, "
        f"{growth_exponent(tail):.2f} over the last {len(tail)} (algorithm); "
        f"{growth_exponent(rows, 'median_total_ms'):.2f} / {growth_exponent(tail, 'median_total_ms'):.2f} whole query"
    )
    if args.json:
        args.json.write_text(json.dumps({"desk": desk, "demo_like": rows}, indent=1))
    if args.plot:
        plot_scalability(desk, rows, args.plot)


def plot_scalability(desk: list[dict], demo_like: list[dict], path: Path) -> None:
    """Latency per query against landmarks, log-log: the desk scene now and before, the demo-like rooms."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6, 4))
    for rows, key, label in ((desk, "median_ms", "desk scene, branch and bound"),
                             (desk, "previous_ms", "desk scene, full enumeration (capped from 235 on)"),
                             (demo_like, "median_ms", "demo-like rooms")):
        axes.loglog([r["landmarks"] for r in rows], [r[key] for r in rows], "o-",
                    label=f"{label}: exponent {growth_exponent(rows, key):.2f}")
    axes.set_xlabel("landmarks")
    axes.set_ylabel("matching + inliers + pose, median ms per query")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
