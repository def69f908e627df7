"""Golden results: what each method decides on every third frame of the five generated scenes, held within the
tolerances of tests/tolerance.py (poses 1e-6 m and rad, scores rtol 1e-9, correspondences and failures exactly,
at most one frame of a run differing, success within one frame at every threshold).

A change that moves results on purpose regenerates the files in a commit of its own, saying what moved:

    .venv/bin/python -m pytest tests/e2e/test_golden.py --force-regen

prints, per run, each frame that moved and each success figure before and after, and rewrites tests/golden/.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from tolerance import compare, decisions
from warm_up import FULL_SIZE_SCENES

from clipclique.localization.results import read_results, results_digest
from clipclique.localization.run import RunSettings, run_and_save

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]  # the repository
GOLDEN = ROOT / "tests" / "golden"
GOLDEN_FORMAT = "clipclique golden results"
SCENES = FULL_SIZE_SCENES  # tests/warm_up.py generates them before the workers start
METHODS = ("clipclique", "sh", "cliploc")
STRIDE = 3  # every third frame: the fifteen runs in well under a minute


def golden_path(scene: str, method: str) -> Path:
    return GOLDEN / f"{scene}.{method}.json"


def golden_text(scene: str, method: str, frames: list[dict]) -> str:
    """A golden file: a header, then one frame a line (a regenerated file's diff shows the frames that moved)."""
    header = json.dumps({"format": GOLDEN_FORMAT, "scene": scene, "method": method, "stride": STRIDE})
    lines = ",\n".join(json.dumps(frame, sort_keys=True) for frame in frames)
    return f'{header[:-1]}, "frames": [\n{lines}\n]}}\n'


def decided(full_size_maps, tmp_path: Path, scene: str, method: str) -> list[dict]:
    out = tmp_path / f"{scene}-{method}"
    run_and_save(RunSettings(scene, method, map_path=full_size_maps(scene), data_root=ROOT / "data", out=out,
                             record=False, stride=STRIDE))
    return decisions(read_results(out / "results.json"))


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("scene", SCENES)
def test_results_hold_the_golden_ones(full_size_maps, tmp_path, scene, method, request, capsys):
    found = decided(full_size_maps, tmp_path, scene, method)
    path = golden_path(scene, method)
    if request.config.getoption("--force-regen"):
        before = json.loads(path.read_text())["frames"] if path.is_file() else None
        moved = "new" if before is None else (compare(before, found).report() or "nothing moved")
        path.parent.mkdir(exist_ok=True)
        path.write_text(golden_text(scene, method, found))
        with capsys.disabled():
            print(f"\n{path.relative_to(ROOT)}: {moved}")
        return
    assert path.is_file(), f"{path} missing: regenerate with --force-regen"
    comparison = compare(json.loads(path.read_text())["frames"], found)
    assert comparison.holds, f"{scene} {method} departs from {path.name}:\n{comparison.report()}"


def test_a_moved_pose_fails_the_comparison():
    """The comparison is not vacuous: the golden demo_desk run with one top-1 pose moved by 1e-4 m in each of two
    frames, or one correspondence changed in two frames, does not hold."""
    frames = json.loads(golden_path("demo_desk", "clipclique").read_text())["frames"]
    posed = [i for i, frame in enumerate(frames) if frame["hypotheses"]]
    assert len(posed) >= 2
    moved = json.loads(json.dumps(frames))
    for i in posed[:2]:
        moved[i]["hypotheses"][0]["translation"][0] += 1e-4
    assert compare(frames, moved).differing.keys() == {frames[i]["index"] for i in posed[:2]}
    assert not compare(frames, moved).holds
    once = json.loads(json.dumps(frames))
    once[posed[0]]["hypotheses"][0]["translation"][0] += 1e-4
    assert compare(frames, once).holds  # one frame may differ (a last-bit tie)
    relabelled = json.loads(json.dumps(frames))
    for i in posed[:2]:
        relabelled[i]["hypotheses"][0]["correspondences"][0][1] += 1
    assert not compare(frames, relabelled).holds


def test_the_same_inputs_give_the_same_bytes(full_size_maps, tmp_path):
    """Determinism: the same run twice in this process, and twice in fresh processes, gives identical results
    (every number of every frame, timings aside)."""
    digests = []
    for attempt in range(2):
        out = tmp_path / f"in-process-{attempt}"
        run_and_save(RunSettings("demo_desk", "clipclique", map_path=full_size_maps("demo_desk"),
                                 data_root=ROOT / "data", out=out, record=False, stride=4))
        digests.append(results_digest(read_results(out / "results.json")["frames"]))
    for attempt in range(2):
        out = tmp_path / f"process-{attempt}"
        subprocess.run([Path(sys.executable).with_name("clipclique-loc"), "run", "demo_desk", "--map",
                        full_size_maps("demo_desk"), "--data-root", ROOT / "data", "--out", out, "--stride", "4",
                        "--no-rrd"], check=True, capture_output=True, env=dict(os.environ, NO_COLOR="1"))
        digests.append(read_results(out / "results.json")["run"]["results_digest"])
    assert len(set(digests)) == 1, digests
