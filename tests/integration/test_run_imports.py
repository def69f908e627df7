"""What a `clipclique-loc run` process imports (issue 20: a whole demo run in 5 s, process start included):
no model or plotting library ever, Rerun only when it records. An import added at a module's top would
otherwise slow every run without failing anything."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from clipclique.backends import load_encoder
from clipclique.io.mapfile import save_map
from clipclique.mapping.build import build_map
from clipclique.resolve import open_scene

pytestmark = pytest.mark.slow
PROBE = ("import atexit, json, sys; atexit.register(lambda: print('MODULES', json.dumps(sorted(sys.modules)))); "
         "from clipclique.localization.cli import main; main()")
NEVER = {"torch", "torchvision", "open_clip", "ultralytics", "cv2", "open3d", "matplotlib", "sklearn", "networkx",
         "igraph", "dask", "distributed", "pandas", "plotly", "pycocotools"}


@pytest.fixture(scope="module")
def demo(tmp_path_factory, demo_data) -> tuple[Path, Path]:
    """A three-frame demo scene and its map."""
    root = demo_data("demo", frames=3)
    map_path = tmp_path_factory.mktemp("map") / "demo.map.npz"
    map, _ = build_map(open_scene("demo", root), load_encoder("simulated"))
    save_map(map, map_path)
    return root, map_path


@pytest.mark.parametrize("record", [False, True], ids=["no-rrd", "recording"])
def test_a_run_imports_no_model_or_plotting_library_and_rerun_only_to_record(demo, tmp_path, record):
    root, map_path = demo
    command = [sys.executable, "-c", PROBE, "run", "demo", "--data-root", str(root), "--map", str(map_path),
               "--out", str(tmp_path / "run"), "-q"] + ([] if record else ["--no-rrd"])
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    modules = {name.split(".")[0] for name in json.loads(done.stdout.split("MODULES ")[-1])}
    assert "numba" in modules and "clipclique" in modules  # the probe saw the run's own imports
    assert sorted(modules & NEVER) == []
    assert ("rerun" in modules) == record


def test_a_recordings_start_imports_no_pyarrow_compute():
    """A recording's start (the map and its annotation context logged) does not import pyarrow.compute (about
    0.1 s of every recorded run)."""
    script = ("import sys, tempfile, pathlib, numpy as np\n"
              "from clipclique.types import Ellipsoids, Map\n"
              "from clipclique.viz import LocalizationRecorder\n"
              "map = Map(Ellipsoids(np.zeros((1, 3)), np.ones((1, 3)), np.eye(3)[None]), np.zeros(1, int), ['chair'],"
              " ['a chair'], np.zeros(1, int))\n"
              "with tempfile.TemporaryDirectory() as folder:\n"
              "    with LocalizationRecorder(pathlib.Path(folder) / 'r.rrd', map, 'x'):\n"
              "        pass\n"
              "print('pyarrow.compute' in sys.modules)\n")
    loaded = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert loaded.stdout.strip() == "False", loaded.stderr
