"""Speed of the core algorithm on synthetic maps (everything here is simulated data).

    .venv/bin/python tools/bench_core.py                 # both parts, default sizes
    .venv/bin/python tools/bench_core.py --counts 50 500 5000 --frames 10

Part 1: matching + inliers + pose for one query against a 50-landmark map, median ms per method.
Part 2: scalability as the paper measures it: one room's landmarks duplicated side by side (50 to
5,000 landmarks), latency per query against landmark count and the fitted growth exponent
(slope of a log-log least-squares line). Also times igraph against networkx's `find_cliques`
on the compatibility graphs that arise, the measurement behind inliers.py's choice.
`scalability()` is importable for other benchmark scripts.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator

import networkx as nx
import numpy as np

from clipclique.config import METHOD_PRESETS, LocalizationConfig, make_config
from clipclique.inliers import compatibility_graph, maximal_cliques
from clipclique.pipeline import LocalizationResult, index_map, localize
from clipclique.synthetic import duplicate_rooms, synthetic_map, synthetic_query
from clipclique.types import Map, Observations

ALGORITHM = ("matching", "inliers", "pose")


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
        algorithm.append(1e3 * sum(timings[s] for s in ALGORITHM))
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
            algorithm.append(1e3 * sum(result.timings[s] for s in ALGORITHM))
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


def clique_engines(counts: list[int], room: int = 50, frames: int = 5, seed: int = 0) -> list[dict]:
    """ms of igraph (as used) and networkx find_cliques on the same compatibility graphs."""
    rows = []
    for count in counts:
        ig, nxs = [], []
        for map, observations, config, result in duplicated_room_queries(count, "clipclique", room, frames, seed):
            edges = compatibility_graph(
                observations.ellipsoids.centers, map.ellipsoids.centers, result.candidates, config.inliers.d_comp
            )
            start = time.perf_counter()
            maximal_cliques(edges, len(result.candidates))
            ig.append(time.perf_counter() - start)
            start = time.perf_counter()
            graph = nx.Graph()
            graph.add_nodes_from(range(len(result.candidates)))
            graph.add_edges_from(edges.tolist())
            [c for c in nx.find_cliques(graph) if len(c) >= 3]
            nxs.append(time.perf_counter() - start)
        rows.append({"landmarks": len(map), "igraph_ms": 1e3 * np.median(ig), "networkx_ms": 1e3 * np.median(nxs)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", type=int, nargs="+", default=[50, 100, 200, 500, 1000, 2000, 5000])
    parser.add_argument("--frames", type=int, default=10, help="queries per landmark count")
    parser.add_argument("--method", default="clipclique", choices=list(METHOD_PRESETS))
    args = parser.parse_args()

    print("Part 1: one query vs a 50-landmark synthetic map (matching + inliers + pose)")
    print(f"{'method':<12}{'median ms':>10}{'p90 ms':>10}{'total ms':>10}")
    for method in METHOD_PRESETS:
        row = single_query(method)
        print(f"{method:<12}{row['median_ms']:>10.2f}{row['p90_ms']:>10.2f}{row['median_total_ms']:>10.2f}")

    print(f"\nPart 2: scalability, {args.method}, duplicated rooms of 50 landmarks")
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

    print("\nClique engines on the same compatibility graphs (median ms)")
    for row in clique_engines(args.counts[:: max(1, len(args.counts) // 3)]):
        print(f"{row['landmarks']:>10}  igraph {row['igraph_ms']:8.2f}  networkx {row['networkx_ms']:8.2f}")


if __name__ == "__main__":
    main()
