"""Reading a ROS bag: peak memory against the bag's length, and frames per second beside the TUM folder.

A demo_tum folder (160 x 120 unless told) is written as a ROS 1 bag and an mcap 1x, 5x and 20x over
(tools/tum_to_bag.py --repeat); each bag, and the folder, is opened and every frame read in a fresh
process, which reports its peak RSS and its frames per second. Peak memory must stay flat in the length
(the reader keeps stamps, not images):

    python tools/bench_bag.py --frames 40
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def read_all(path: str) -> dict[str, float]:
    """Open `path` (a bag or a TUM folder), read every frame; its frames, seconds, and this process's peak RSS
    after the imports and at the end (what the reading added is their difference)."""
    from clipclique.datasets import open_sequence

    imported = peak_rss_mb()
    clock = time.perf_counter()
    sequence = open_sequence(path)
    opened = time.perf_counter() - clock
    for i in range(len(sequence)):
        sequence[i]
    seconds = time.perf_counter() - clock
    return {"frames": len(sequence), "open_s": opened, "seconds": seconds, "imports_rss_mb": imported,
            "peak_rss_mb": peak_rss_mb()}


def peak_rss_mb() -> float:
    """This process's peak RSS, VmHWM: getrusage's ru_maxrss survives exec, so a child would report its parent's."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def measured(path: Path) -> dict[str, float]:
    output = subprocess.run([sys.executable, __file__, "--read", str(path)], check=True, capture_output=True, text=True)
    return json.loads(output.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames of the demo_tum walk written once")
    parser.add_argument("--size", default="160x120", help="WIDTHxHEIGHT")
    parser.add_argument("--repeats", default="1,5,20")
    parser.add_argument("--read", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.read:
        print(json.dumps(read_all(args.read)))
        return
    sys.path.insert(0, str(ROOT / "tools"))
    from tum_to_bag import write_bag

    from clipclique.sim.demo import DEMO_SCENES, generate

    width, height = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory() as work:
        folder = Path(work) / "demo_tum"
        folder.mkdir()
        generate(
            folder,
            "demo_tum",
            dataclasses.replace(DEMO_SCENES["demo_tum"], num_frames=args.frames, width=width, height=height),
        )
        folder_run = measured(folder)
        print(
            f"TUM folder: {folder_run['frames']} frames, {folder_run['frames'] / folder_run['seconds']:.0f} frames/s, "
            f"peak RSS {folder_run['peak_rss_mb']:.0f} MB ({folder_run['imports_rss_mb']:.0f} after the imports)"
        )
        for storage in ("ros1", "mcap"):
            for repeat in (int(r) for r in args.repeats.split(",")):
                out = Path(work) / f"{storage}-{repeat}" / ("demo_tum.bag" if storage == "ros1" else "demo_tum")
                write_bag(folder, out, storage, "tum", repeat)
                size = sum(p.stat().st_size for p in ([out] if out.is_file() else out.iterdir()))
                run = measured(out)
                print(
                    f"{storage} x{repeat}: {run['frames']} frames, {size / 2**20:.0f} MB, "
                    f"opened in {run['open_s']:.2f} s, "
                    f"{run['frames'] / run['seconds']:.0f} frames/s (opening included), "
                    f"peak RSS {run['peak_rss_mb']:.0f} MB ({run['imports_rss_mb']:.0f} after the imports)"
                )


if __name__ == "__main__":
    main()
