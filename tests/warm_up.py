"""What a fresh clone's test session makes first, before its workers start (tests/conftest.py runs it).

    python tests/warm_up.py kernels   # numba compiles every kernel a run reaches, into its on-disk cache
    python tests/warm_up.py scenes    # the full-size generated scenes the golden results read, under data/

On a fresh clone the first run of each kernel compiles it (about 75 s for a localization run), and every
worker and every CLI subprocess that starts before the cache holds it compiles it again; the golden
results' scenes are rendered once (about 80 s). The two jobs run side by side, one per core; with the
cache and the scenes already there each takes a second or two.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FULL_SIZE_SCENES = ("demo", "demo_tum", "demo_apartment", "demo_desk", "demo_clutter")  # the golden results' scenes


def stale_kernels(modules: dict[str, Path], imported: dict[str, set[str]]) -> list[Path]:
    """numba's cache files of `modules` (name -> file) that are older than a module with kernels (`njit` in its
    text) that their module imports, directly or not (`imported`: name -> the project modules it imports). numba
    checks a cached kernel against its own file only, yet a kernel keeps the machine code of the kernels it calls
    in other modules: after an edit there, the cache would run the old code until its own file changed."""
    stale: list[Path] = []
    kernel_modules = {name for name, path in modules.items() if "njit" in path.read_text(encoding="utf-8")}
    for name, path in modules.items():
        cached = list((path.parent / "__pycache__").glob(f"{path.stem}.*.nb[ic]"))
        if not cached:
            continue
        seen, todo = {name}, [name]
        while todo:
            for other in imported.get(todo.pop(), set()) - seen:
                seen.add(other)
                todo.append(other)
        newest = max(modules[other].stat().st_mtime for other in seen if other == name or other in kernel_modules)
        stale += [file for file in cached if file.stat().st_mtime < newest]
    return stale


def drop_stale_kernels() -> None:
    """Delete `stale_kernels` of the package, so that the session compiles what the sources say (tests/conftest.py
    runs it before every session, serial or parallel: well under a second)."""
    sys.path.insert(0, str(ROOT))
    from tests.unit.test_architecture import imports, sources

    modules = {name: path for name, path in sources().items() if name.startswith("clipclique")}
    for file in stale_kernels(modules, {name: set(imports(path, set(modules))) for name, path in modules.items()}):
        file.unlink(missing_ok=True)


def kernels() -> None:
    """Two frames of each generated scene kind localized with every method, and a map aligned to itself."""
    import dataclasses

    from clipclique.backends import load_encoder
    from clipclique.config import METHOD_PRESETS, make_config
    from clipclique.io.mapfile import save_map
    from clipclique.localization.run import RunSettings, run_and_save
    from clipclique.mapping.build import build_map
    from clipclique.pipeline import align_maps
    from clipclique.resolve import open_scene
    from clipclique.sim.demo import DEMO_SCENES, generate

    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        for name in ("demo_desk", "demo_apartment"):  # a TUM and a ScanNet layout; simulated YOLO and gt
            folder = root / "demo" / name
            generate(folder, name, dataclasses.replace(DEMO_SCENES[name], num_frames=2, width=160, height=120))
            map, _ = build_map(open_scene(str(folder)), load_encoder("simulated"))
            save_map(map, root / f"{name}.map.npz")
            for method in METHOD_PRESETS:
                run_and_save(RunSettings(str(folder), method, map_path=root / f"{name}.map.npz",
                                         out=root / "loc" / name / method, record=False))
            align_maps(map, map, make_config("clipclique"))


def scenes() -> None:
    from clipclique.sim.demo import ensure_scene

    for name in FULL_SIZE_SCENES:
        ensure_scene(name, ROOT / "data")


if __name__ == "__main__":
    jobs = {"kernels": kernels, "scenes": scenes}
    if len(sys.argv) != 2 or sys.argv[1] not in jobs:
        sys.exit(f"usage: {sys.argv[0]} {' | '.join(jobs)}")
    jobs[sys.argv[1]]()
