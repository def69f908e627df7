"""What `make demo` installs: the core alone. The demo runs only simulated parts, so it must run where
torch, open_clip and ultralytics (the models extra: 7.5 GB with PyPI's CUDA libraries) are absent."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from clipclique.sim.demo import DEMO_SCENES, generate

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
MODEL_MODULES = ("torch", "torchvision", "open_clip", "ultralytics", "cv2")
BLOCKER = f"""import importlib.abc, sys
class _Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {MODEL_MODULES!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}} (not installed by make demo)", name=name)
        return None
sys.meta_path.insert(0, _Absent())
"""


def test_make_demo_installs_no_models_and_make_test_does(tmp_path):
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    demo = subprocess.run(["make", "-n", "demo"], cwd=tmp_path, capture_output=True, text=True, check=True).stdout
    installs = [line for line in demo.splitlines() if "pip install" in line]
    assert installs and not any("torch" in line or "[" in line for line in installs), installs
    assert "-e ." in installs[-1] and "tools/demo.py" in demo
    test = subprocess.run(["make", "-n", "test"], cwd=tmp_path, capture_output=True, text=True, check=True).stdout
    assert "torch==" in test and "'.[models,dev]'" in test and "pytest" in test
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = " ".join(project["dependencies"])
    assert not any(module in core for module in ("torch", "open_clip", "ultralytics", "opencv"))


@pytest.mark.slow
def test_the_demo_commands_run_without_the_models_extra(tmp_path):
    data = tmp_path / "data"
    generate(data / "demo" / "demo", "demo", dataclasses.replace(DEMO_SCENES["demo"], num_frames=4))
    (tmp_path / "block").mkdir()
    (tmp_path / "block" / "sitecustomize.py").write_text(BLOCKER)
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(tmp_path / "block"), str(ROOT)]),
                        "CLIPCLIQUE_DATA": str(data)}
    for command in (["clipclique-map", "build", "demo", "-q"], ["clipclique-loc", "run", "demo", "-q"]):
        done = subprocess.run([str(BIN / command[0]), *command[1:]], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        assert "Traceback" not in done.stderr
    assert (tmp_path / "outputs" / "loc" / "demo" / "clipclique" / "results.json").is_file()
    probe = subprocess.run([sys.executable, "-c", "import torch"], env=env, capture_output=True, text=True)
    assert "not installed by make demo" in probe.stderr  # the blocker did block


@pytest.mark.slow
def test_the_wheel_installs_one_top_level_package(tmp_path):
    """`pip install .` puts `clipclique` (and its dist-info) in site-packages, no generic name beside it. Built from
    a copy of the sources: a build in place leaves build/ in the repository."""
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    shutil.copytree(ROOT / "clipclique", source / "clipclique", ignore=shutil.ignore_patterns("__pycache__"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", tmp_path,
                    source], check=True, capture_output=True, cwd=tmp_path)
    wheel, = tmp_path.glob("clipclique-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        record, = (name for name in archive.namelist() if name.endswith(".dist-info/RECORD"))
        paths = [line.split(",")[0] for line in archive.read(record).decode().splitlines() if line]
    tops = {path.split("/")[0] for path in paths}
    assert tops == {"clipclique", record.split("/")[0]}, tops
    assert {"clipclique/mapping/cli.py", "clipclique/localization/cli.py", "clipclique/benchmark/cli.py",
            "clipclique/data/confidence.json"} <= set(paths)
    entry_points = archive_text(wheel, record.replace("RECORD", "entry_points.txt"))
    assert "clipclique-loc = clipclique.localization.cli:main" in entry_points


def archive_text(wheel: Path, name: str) -> str:
    with zipfile.ZipFile(wheel) as archive:
        return archive.read(name).decode()
