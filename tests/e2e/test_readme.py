"""The README and the pages of docs/ as a new user runs them: every `sh` block as written, the library snippet,
the TOML example.

Blocks run in order (the README's, then each page's in PAGES order, the order the README once held them in) in
one scratch folder that looks like the repository root (tools/, tests/,
.venv/ and pyproject.toml linked in), with `CLIPCLIQUE_DATA` pointing at demo scenes shortened to 12 frames, so every
command runs as written in a minute or two in all. Blocks that cannot run here are listed in
SKIPPED with the reason; a block that is neither run nor listed fails the test.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from clipclique.config import make_config
from clipclique.sim.demo import DEMO_SCENES

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]  # the repository
# the pages whose commands run, in order: a page's commands may use what an earlier page's made
PAGES = ["README.md", "docs/scenes.md", "docs/data.md", "docs/cli.md", "docs/own_maps.md",
         "docs/methods.md", "docs/verification.md", "docs/models.md", "docs/recordings.md",
         "docs/benchmarks.md", "docs/library.md", "docs/architecture.md"]
# pages whose blocks make all they use (their own maps and bags): they run apart from PAGES, in order, so that
# another worker can take them (tests/conftest.py's scope_of)
SELF_CONTAINED = ["docs/import_export.md", "docs/bags.md"]
# pages whose commands do not run here yet, and why (each is a debt: move it into PAGES when its blocks run)
NOT_RUN = {
    "docs/REAL_SCENES.md": "its block generates and localizes the 900-frame demo_sparse (many minutes)",
}
TEXT = {page: (ROOT / page).read_text() for page in PAGES + SELF_CONTAINED}
FRAMES = 12
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.MULTILINE | re.DOTALL)

# first line of a block -> why the test does not run it
SKIPPED = {
    "make demo": "installs the project and runs the full demo (minutes); its steps are the blocks below",
    "sudo apt-get install libusb-1.0-0 libgomp1": "installs system packages",
    "clipclique-map build scene0002_00 --data-root /datasets": "needs the ScanNet and TUM RGB-D datasets",
    "clipclique-loc run scene0002_00 --encoder open_clip:ViT-L-14/openai": "needs real datasets and model weights",
    "evo_ape tum outputs/loc/demo_tum/clipclique/groundtruth.tum outputs/loc/demo_tum/clipclique/poses.tum":
        "evo is not a dependency (`pip install evo`); its input files are checked by test_evo_files_pair_up",
    "rerun outputs/loc/demo/clipclique/recording.rrd": "opens the viewer's window",
    "make docs": "reruns the demo and the benchmark (minutes); tests/e2e/test_bench.py checks what it wrote",
    "make test": "runs this test suite",
    "python -m pytest -q tests/unit/inliers/test_inliers.py tests/unit/test_config.py": "runs tests this suite runs",
    "python -m pytest tests/e2e/test_golden.py --force-regen": "rewrites the golden results (tests/e2e/test_golden.py "
                                                               "runs the same runs and compares them)",
    "pip install dask-jobqueue": "starts a SLURM cluster (none here); the local cluster is tested in "
                                 "tests/integration/test_bench_engine.py",
    ".venv/bin/python tools/fit_confidence.py scene0002_00 fr2 --out my_confidence.json": "needs real datasets",
    "mkdir -p data/tum && curl -L "
    "https://cvg.cit.tum.de/rgbd/dataset/freiburg2/rgbd_dataset_freiburg2_desk.tgz | tar xz -C data/tum":
        "downloads TUM fr2/desk and needs a published object map; the block after it runs the same commands on "
        "generated files",
    "clipclique-map build demo_tum -q": "prints the example below it: test_printed_examples_are_current runs it on the "
                                        "full scenes and compares",
    "python tools/fit_align_confidence.py --seeds 200": "fits the alignment confidence on 400 seeds of generated "
                                                        "map pairs and aligns 3,000 more (minutes); "
                                                        "tests/unit/multiframe/test_mapalign.py holds the fitted "
                                                        "model to its cases",
    "python tools/bench_bag.py --frames 40": "a benchmark: writes and reads bags 1, 5 and 20 times the demo's length "
                                             "(minutes); tests/unit/test_rosbag.py checks the lazy reading",
    ".venv/bin/python tools/bench_window.py --step 1": "localizes both realistic scenes 40 times each (minutes); "
                                                       "tests/integration/test_bench_window.py runs it on a few frames",
}


def blocks(language: str, pages: list[str] = PAGES + SELF_CONTAINED) -> list[str]:
    return [body for page in pages for lang, body in FENCE.findall(TEXT[page]) if lang == language]


def block_id(block: str) -> str:
    return block.strip().splitlines()[0].split("#")[0].strip()


SH_BLOCKS = blocks("sh", PAGES)
OWN_BLOCKS = blocks("sh", SELF_CONTAINED)


def test_every_page_with_commands_is_run():
    """A new page of docs/ with an `sh` block joins PAGES, so its commands cannot go stale."""
    commands = {f"docs/{path.name}" for path in (ROOT / "docs").glob("*.md") if "```sh\n" in path.read_text()}
    run = set(PAGES) | set(SELF_CONTAINED) | set(NOT_RUN)
    assert commands <= run, commands - run


def test_every_code_block_says_what_it_is():
    """An untagged block could be a command nobody tests: each is sh, text, python or toml."""
    languages = [lang for page in PAGES + SELF_CONTAINED for lang, _ in FENCE.findall(TEXT[page])]
    assert set(languages) <= {"sh", "text", "python", "toml", "json"}, languages
    assert set(SKIPPED) <= {block_id(b) for b in SH_BLOCKS + OWN_BLOCKS}  # the list names blocks that exist


@pytest.fixture(scope="module")
def workspace(tmp_path_factory, demo_data) -> tuple[Path, dict[str, str]]:
    """A scratch repository root: tools, tests and .venv linked, shortened demo data elsewhere."""
    root = tmp_path_factory.mktemp("readme")
    for name in ("tools", "tests", ".venv", "pyproject.toml"):
        (root / name).symlink_to(ROOT / name)
    data = demo_data(*DEMO_SCENES, frames=FRAMES, size=None)
    (root / "data").symlink_to(data, target_is_directory=True)  # as make demo leaves it: data/demo/<scene>
    env = os.environ | {"CLIPCLIQUE_DATA": str(data), "TERM": "dumb"}
    env.pop("VIRTUAL_ENV", None)
    env["PATH"] = os.pathsep.join(p for p in env["PATH"].split(os.pathsep) if not p.startswith(str(ROOT / ".venv")))
    return root, env


def run_shell(script: str, root: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=root, env=env, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.parametrize("block", SH_BLOCKS, ids=[block_id(b) for b in SH_BLOCKS])
def test_readme_block_runs(block, workspace):
    run_block(block, workspace)


@pytest.mark.parametrize("block", OWN_BLOCKS, ids=[block_id(b) for b in OWN_BLOCKS])
def test_self_contained_page_block_runs(block, workspace):
    run_block(block, workspace)


def run_block(block: str, workspace: tuple[Path, dict[str, str]]) -> None:
    if block_id(block) in SKIPPED:
        pytest.skip(SKIPPED[block_id(block)])
    root, env = workspace
    # as the README says first: `. .venv/bin/activate` in the repository root
    done = run_shell(f". .venv/bin/activate\n{block}", root, env)
    assert done.returncode == 0, f"{block}\n--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"
    assert "Traceback" not in done.stderr


def test_library_snippet_prints_a_pose(workspace):
    root, env = workspace
    (snippet,) = [b for b in blocks("python") if "seconds per stage" in b]  # the stage-by-stage example
    if not (root / "outputs" / "maps" / "demo.map.npz").is_file():
        run_shell(". .venv/bin/activate\nclipclique-map build demo -q --no-rrd", root, env)
    done = subprocess.run([sys.executable, "-c", snippet], cwd=root, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    pose = [line for line in lines if line.startswith("pose")]
    assert pose, done.stdout
    start = lines.index(pose[0]) + 1
    rows = [re.findall(r"-?\d+\.\d*", line) for line in lines[start:start + 4]]
    assert [len(row) for row in rows] == [4, 4, 4, 4]  # the 4 x 4 camera-to-world matrix
    assert [float(v) for v in rows[3]] == [0.0, 0.0, 0.0, 1.0]
    assert any(line.startswith("seconds per stage") for line in lines)


def test_the_front_page_example_localizes_a_demo_frame(workspace):
    """The README's Localizer example as written: a 4 x 4 pose or the failure (test_api.py checks its numbers)."""
    root, env = workspace
    (snippet,) = [b for b in FENCE.findall(TEXT["README.md"]) if b[0] == "python"]
    if not (root / "outputs" / "maps" / "demo.map.npz").is_file():
        run_shell(". .venv/bin/activate\nclipclique-map build demo -q --no-rrd", root, env)
    done = subprocess.run([sys.executable, "-c", snippet[1]], cwd=root, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    rows = [re.findall(r"-?\d+\.\d*", line) for line in done.stdout.splitlines()]
    assert [len(row) for row in rows] == [4, 4, 4, 4] and [float(v) for v in rows[3]] == [0, 0, 0, 1], done.stdout


def test_toml_example_is_a_valid_configuration(tmp_path):
    (example,) = blocks("toml")
    tomllib.loads(example)
    path = tmp_path / "my.toml"
    path.write_text(example)
    config = make_config("clipclique", path)
    assert config.inliers.d_comp == tomllib.loads(example)["inliers"]["d_comp"]


def test_evo_files_pair_up(workspace):
    """What the skipped evo block reads: groundtruth.tum and poses.tum share their timestamps."""
    root, env = workspace
    folder = root / "outputs" / "loc" / "demo_tum" / "clipclique"
    if not (folder / "poses.tum").is_file():
        run_shell(". .venv/bin/activate\nclipclique-loc run demo_tum -q --no-rrd", root, env)
    stamps = {name: [line.split()[0] for line in (folder / name).read_text().splitlines() if not line.startswith("#")]
              for name in ("groundtruth.tum", "poses.tum")}
    assert len(stamps["groundtruth.tum"]) == FRAMES
    assert set(stamps["poses.tum"]) <= set(stamps["groundtruth.tum"]) and stamps["poses.tum"]
    # what the README says of evo_ape's figures: its median and mean are results.json's TE median and mean
    positions = {name: {line.split()[0]: np.array(line.split()[1:4], float) for line in
                        (folder / name).read_text().splitlines() if not line.startswith("#")}
                 for name in ("groundtruth.tum", "poses.tum")}
    ape = [np.linalg.norm(p - positions["groundtruth.tum"][t]) for t, p in positions["poses.tum"].items()]
    summary = json.loads((folder / "results.json").read_text())["summary"]
    assert np.median(ape) == pytest.approx(summary["te_median_m"], abs=2e-6)  # poses.tum rounds to the micrometre
    assert np.mean(ape) == pytest.approx(summary["te_mean_m"], abs=2e-6)
    if shutil.which("evo_ape"):
        done = subprocess.run(["evo_ape", "tum", folder / "groundtruth.tum", folder / "poses.tum"], capture_output=True,
                              text=True)
        assert done.returncode == 0, done.stderr


def test_printed_examples_are_current():
    """What the docs show a command printing is what it prints today (make docs rewrites it: tools/docs_outputs.py)."""
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "docs_outputs.py"), "--check"], cwd=ROOT,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr


def test_a_stale_printed_example_fails_the_check_and_a_timing_does_not(tmp_path):
    page = tmp_path / "page.md"
    tool = [sys.executable, str(ROOT / "tools" / "docs_outputs.py")]
    example = "```sh\nprintf 'Method TE ms\\nsh 0.18 %s\\n' 0.7\n```\n\n<!-- printed by the block above -->\n\n"
    page.write_text(example + "```text\nMethod TE ms\nsh 0.23 0.7\n```\n")
    stale = subprocess.run([*tool, "--check", str(page)], capture_output=True, text=True, timeout=60)
    assert stale.returncode == 1 and "-sh 0.23" in stale.stdout and "+sh 0.18" in stale.stdout, stale.stdout
    assert subprocess.run([*tool, "--write", str(page)], capture_output=True, timeout=60).returncode == 0
    assert page.read_text().endswith("```text\nMethod TE ms\nsh 0.18 0.7\n```\n")
    page.write_text(page.read_text().replace("0.18 0.7", "0.18 1.4"))  # another run's timing: not a change
    assert subprocess.run([*tool, "--check", str(page)], capture_output=True, timeout=60).returncode == 0
    timings = ("```sh\nprintf 'Median time [ms]\\ndet. fit\\n%s  1.8\\n' 18.8\n```\n\n"
               "<!-- printed by the block above -->\n\n")
    page.write_text(timings + "```text\nMedian time [ms]\ndet. fit\n 9.8  1.8\n```\n")  # a digit less, re-padded
    assert subprocess.run([*tool, "--check", str(page)], capture_output=True, timeout=60).returncode == 0
    page.write_text(timings + "```text\nMedian time [ms]\ndet. enc.\n 9.8  1.8\n```\n")  # a header changed
    assert subprocess.run([*tool, "--check", str(page)], capture_output=True, timeout=60).returncode == 1
