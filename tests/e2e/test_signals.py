"""SIGTERM or Ctrl-C during a run, and --no-rrd after a recorded run: nothing half-written, nothing stale.

The signal tests run `clipclique-loc` as a process (a signal needs one) and interrupt it while
its recording is being written.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from clipclique.resolve import open_scene
from clipclique.backends import load_encoder
from clipclique.mapfile import save_map
from localization.cli import app
from mapping.build import build_map

pytestmark = pytest.mark.slow
LOC = Path(sys.executable).with_name("clipclique-loc")


@pytest.fixture(scope="module")
def demo(tmp_path_factory, demo_data) -> Path:
    """A 60-frame demo at 160 x 120, its map, and the outputs of an earlier recorded run in loc/."""
    root = tmp_path_factory.mktemp("signals")
    (root / "demo").symlink_to(demo_data("demo", frames=60) / "demo", target_is_directory=True)
    map, _ = build_map(open_scene("demo", root), load_encoder("simulated"))
    save_map(map, root / "demo.map.npz")
    result = CliRunner().invoke(app, args(root, "--max-frames", "3"))
    assert result.exit_code == 0, result.output
    return root


def args(root: Path, *extra: str) -> list[str]:
    return ["run", "demo", "--data-root", str(root), "--map", str(root / "demo.map.npz"), "--out", str(root / "loc"), *extra]


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_mid_run_leaves_no_partial_and_the_previous_outputs(demo, signum):
    before = digests(demo / "loc")
    assert set(before) == {"results.json", "poses.tum", "groundtruth.tum", "config.json", "recording.rrd"}
    # A shell starting a job in the background (`make test &`, nohup) hands it SIGINT ignored, and
    # Python keeps an inherited SIG_IGN: the child gets the default back, as a terminal gives it.
    process = subprocess.Popen([str(LOC), *args(demo)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               env={**os.environ, "COLUMNS": "200"},
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while not any(p.name.endswith(".partial") for p in (demo / "loc").iterdir()):  # the recording has begun
        assert process.poll() is None and time.monotonic() < deadline, "the run ended before it could be interrupted"
        time.sleep(0.01)
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode != 0
    assert b"Traceback" not in stderr
    assert digests(demo / "loc") == before  # no *.partial, earlier files byte-identical


def test_no_rrd_after_a_recorded_run_removes_the_stale_recording_and_says_so(demo, tmp_path):
    out = tmp_path / "loc"
    out.mkdir()
    for name in ("results.json", "poses.tum", "groundtruth.tum", "config.json", "recording.rrd"):
        (out / name).write_bytes((demo / "loc" / name).read_bytes())
    command = args(demo, "--max-frames", "2", "--no-rrd")
    command[command.index("--out") + 1] = str(out)
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == ["config.json", "groundtruth.tum", "poses.tum", "results.json"]
    assert f"note: {out / 'recording.rrd'} of an earlier run was removed (--no-rrd: it would not match these results)" \
        in result.output.replace("\n", "")


def test_map_build_with_no_rrd_removes_the_earlier_maps_recording_and_says_so(demo, tmp_path):
    from mapping.cli import app as map_app

    out = tmp_path / "demo.map.npz"
    (tmp_path / "demo.map.rrd").write_bytes(b"an earlier map's recording")
    result = CliRunner().invoke(map_app, ["build", "demo", "--data-root", str(demo), "--out", str(out), "--no-rrd"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo.map.npz"]
    assert f"removed {tmp_path / 'demo.map.rrd'}, the recording of an earlier map (--no-rrd)" in result.output.replace("\n", "")
