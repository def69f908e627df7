"""Benchmark: map building on a ScanNet-size scene (about 80,000 vertices, 50 objects), encoder excluded.

Writes a procedural room in the ScanNet scan layout (labelled mesh, segments, aggregation) to
a temporary folder, then times what `clipclique-map build` does with it: reading the scene
(ply + json) and fitting every instance (outlier removal + PCA box). Run:

    .venv/bin/python tools/bench_mapping.py [--repeats 5] [--threads 2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2, help="CPU threads open3d and numpy may use")
    parser.add_argument("--spacing", type=float, default=0.045, help="mesh vertex spacing on furniture (m)")
    args = parser.parse_args()
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = str(args.threads)

    from clipclique.datasets.scannet import ScanNetScene
    from clipclique.mapping.build import build_map
    from clipclique.sim.demo import write_scannet_mesh
    from clipclique.sim.procedural import make_room

    room = make_room(seed=7, spacing=args.spacing, boxes=6)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "scene9999_00"
        folder.mkdir()
        write_scannet_mesh(folder, folder.name, room)
        times, fits = [], []
        for _ in range(args.repeats):
            start = time.perf_counter()
            landmarks, report = build_map(ScanNetScene(folder), encoder=None)
            times.append(time.perf_counter() - start)
            fits.append(report.timings["fit"])
    print(f"scene: {len(room.vertices):,} vertices, {len(room.objects)} objects -> {len(landmarks)} landmarks "
          f"({sum(report.structure.values())} structure left out, "
          f"{sum(len(v) for v in report.skipped.values())} skipped)")
    print(f"map build (read + fit, encoder excluded), {args.repeats} runs, {args.threads} threads: "
          f"median {statistics.median(times):.2f} s, min {min(times):.2f} s, max {max(times):.2f} s "
          f"(fit alone: median {statistics.median(fits):.2f} s)")


if __name__ == "__main__":
    main()
