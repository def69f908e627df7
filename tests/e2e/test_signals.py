"""SIGTERM or Ctrl-C during a run, and --no-rrd after a recorded run: nothing half-written, nothing stale.

The signal tests run `clipclique-loc` as a process (a signal needs one) and interrupt it while
its recording is being written.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from clipclique.backends import load_encoder
from clipclique.io.mapfile import save_map
from clipclique.localization.cli import app
from clipclique.mapping.build import build_map
from clipclique.resolve import open_scene

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
    return ["run", "demo", "--data-root", str(root), "--map", str(root / "demo.map.npz"), "--out", str(root / "loc"),
            *extra]


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_mid_run_leaves_no_partial_and_the_previous_outputs(demo, signum):
    before = digests(demo / "loc")
    assert set(before) == {"results.json", "frames.csv", "poses.tum", "groundtruth.tum", "config.json", "recording.rrd"}
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


def test_no_rrd_never_deletes_the_recording_and_says_each_time_it_shows_other_results(demo, tmp_path):
    out = tmp_path / "loc"
    out.mkdir()
    for name in ("results.json", "frames.csv", "poses.tum", "groundtruth.tum", "config.json", "recording.rrd"):
        (out / name).write_bytes((demo / "loc" / name).read_bytes())  # a recorded run of 3 frames
    recorded = (out / "recording.rrd").read_bytes()

    def run(*extra: str) -> tuple[subprocess.CompletedProcess, dict]:
        command = args(demo, *extra)
        command[command.index("--out") + 1] = str(out)
        done = subprocess.run([str(LOC), *command], capture_output=True, text=True, timeout=300,
                              env={**os.environ, "COLUMNS": "200"})
        assert done.returncode == 0, done.stderr
        assert (out / "recording.rrd").read_bytes() == recorded  # byte-identical, never deleted
        return done, json.loads((out / "results.json").read_text())["run"]

    stale = f"{out / 'recording.rrd'} beside these results is an earlier run's and does not show them"
    for _ in range(2):  # every time, not only the first
        done, described = run("--max-frames", "2", "--no-rrd")
        assert stale in " ".join(done.stdout.split())
        assert described["recording"] == {"file": "recording.rrd",
                                          "results_digest": described["recording"]["results_digest"],
                                          "matches": False}
        assert described["recording"]["results_digest"] != described["results_digest"]
    quiet, _ = run("--max-frames", "2", "--no-rrd", "-q")
    assert f"clipclique-loc: warning: {out / 'recording.rrd'} is an earlier run's and does not show these results" \
        in quiet.stderr
    same, described = run("--max-frames", "3", "--no-rrd")  # the recorded run's settings: the recording shows these
    assert described["recording"]["matches"] and "earlier run's and does not show" not in same.stdout + same.stderr
    assert "an earlier run's with the same results" in same.stdout


def test_map_build_with_no_rrd_keeps_the_earlier_maps_recording_and_says_when_it_shows_another_map(demo, tmp_path):
    from clipclique.mapping.cli import app as map_app

    out = tmp_path / "demo.map.npz"
    (tmp_path / "demo.map.rrd").write_bytes(b"an earlier map's recording")
    result = CliRunner().invoke(map_app, ["build", "demo", "--data-root", str(demo), "--out", str(out), "--no-rrd"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "demo.map.rrd").read_bytes() == b"an earlier map's recording"
    assert (f"note: {tmp_path / 'demo.map.rrd'} is an earlier map's recording and does not show this map"
            in result.output.replace("\n", ""))  # no map was there before: the recording shows another
    again = CliRunner().invoke(map_app, ["build", "demo", "--data-root", str(demo), "--out", str(out), "--no-rrd"])
    assert again.exit_code == 0 and "does not show this map" not in again.output  # the same landmarks as before
