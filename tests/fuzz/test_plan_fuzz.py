"""Hostile plan files and options of `clipclique-bench`: each one line naming the file (or option) and
what is wrong, exit 2, before any work (no output folder, no cache)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from clipclique.benchmark.cli import app

RUNNER = CliRunner()
LATIN1 = "scenes = [\"d\u00e9mo\"]".encode("latin-1")

PLANS: dict[str, bytes | None] = {
    "not-toml": b"scenes = [demo",
    "latin1": LATIN1,
    "empty": b"",
    "no-scenes": b"scenes = []",
    "scenes-a-string": b'scenes = "demo"',
    "scene-a-number": b"scenes = [3]",
    "scene-empty": b'scenes = [""]',
    "unknown-entry": b'scenes = ["demo"]\nworkers = 2',
    "unknown-method": b'scenes = ["demo"]\nmethods = ["fastest"]',
    "no-methods": b'scenes = ["demo"]\nmethods = []',
    "stride-zero": b'scenes = ["demo"]\nstride = 0',
    "stride-a-bool": b'scenes = ["demo"]\nstride = true',
    "stride-a-float": b'scenes = ["demo"]\nstride = 1.5',
    "max-frames-negative": b'scenes = ["demo"]\nmax_frames = -1',
    "grid-a-list": b'scenes = ["demo"]\ngrid = [1, 2]',
    "grid-empty-values": b'scenes = ["demo"]\n[grid]\n"inliers.d_comp" = []',
    "grid-table-values": b'scenes = ["demo"]\n[grid]\n"inliers.d_comp" = [{a = 1}]',
    "grid-unknown-key": b'scenes = ["demo"]\n[grid]\n"inliers.nothing" = [1]',
    "grid-wrong-type": b'scenes = ["demo"]\n[grid]\n"inliers.d_comp" = ["far"]',
    "grid-out-of-range": b'scenes = ["demo"]\n[grid]\n"inliers.d_comp" = [-1.0]',
    "grid-too-large": b'scenes = ["demo"]\n[grid]\n'
    + b"".join(b'"k%d" = [%s]\n' % (i, b",".join(b"%d" % j for j in range(40))) for i in range(4)),
    "grid-deep": b'scenes = ["demo"]\n[grid.' + b".".join([b"a"] * 3000) + b"]\nb = 1",
    "glob-matches-nothing": b'scenes = ["/nonexistent/scene*"]',
    "huge": b"# " + b"x" * (2 << 20),
    "nul": b'scenes = ["demo\x00"]',
    "folder": None,
    "window-a-string": b'scenes = ["demo"]\nwindow = "3"',
    "same-place-a-number": b'scenes = ["demo"]\nsame_place = 1',
    "map-a-list": b'scenes = ["demo"]\nmap = ["a.map.npz"]',
    "depth-scale-a-string": b'scenes = ["demo"]\ndepth_scale = "0.001"',
    "gt-frames-a-number": b'scenes = ["demo"]\ngt_frames = 1',
    "groundtruth-a-list": b'scenes = ["demo"]\ngroundtruth = ["gt.txt"]',
    "rgb-topic-a-table": b'scenes = ["demo"]\n[rgb_topic]\nname = "/camera/rgb"',
}


@pytest.mark.parametrize("name", sorted(PLANS))
def test_a_hostile_plan_is_one_line_exit_2_naming_the_file(name: str, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    plan = tmp_path / f"{name}.toml"
    plan.mkdir() if PLANS[name] is None else plan.write_bytes(PLANS[name])
    result = RUNNER.invoke(app, ["--plan", str(plan), "--out", "out", "--cache", "cache"])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2, f"exit {result.exit_code}: {result.output[-2000:]} {result.exception!r}"
    assert len(lines) == 1 and lines[0].startswith("clipclique-bench: error: "), result.output
    assert str(plan) in lines[0], lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [plan.name]  # no output, no cache


@pytest.mark.parametrize(("args", "named"), [
    ([], "no scenes"),
    (["demo", "--grid", "inliers.d_comp"], "inliers.d_comp"),
    (["demo", "--grid", "=0.2"], "=0.2"),
    (["demo", "--grid", "inliers.d_comp=0.2,,0.3"], "0.2,,0.3"),
    (["demo", "--grid", "inliers.d_comp=x"], "inliers.d_comp"),
    (["demo", "--methods", "clipclique,best"], "best"),
    (["demo", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler"),
    (["demo", "--plan", "p.toml"], "p.toml"),
    (["no_such_scene"], "no_such_scene"),
])
def test_hostile_options_are_one_line_exit_2(args: list[str], named: str, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.toml").write_text('scenes = ["demo"]')
    result = RUNNER.invoke(app, [*args, "--out", "out", "--cache", "cache"])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2, f"exit {result.exit_code}: {result.output[-2000:]} {result.exception!r}"
    assert len(lines) == 1 and lines[0].startswith("clipclique-bench: error: ") and named in lines[0], result.output
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


def test_the_documented_plan_example_reads_as_its_runs(repository: Path, tmp_path: Path):
    from clipclique.benchmark.plan import read_plan, runs

    readme = (repository / "docs" / "cli.md").read_text()  # clipclique-bench's section
    example = readme.split("  ```toml\n", 1)[1].split("  ```", 1)[0]
    path = tmp_path / "plan.toml"
    path.write_text("\n".join(line.removeprefix("  ") for line in example.splitlines()))
    settings = runs(read_plan(path), tmp_path / "out", None, record=False)
    assert [(s.sequence, s.method, s.overrides, s.max_frames) for s in settings][:3] == [
        ("demo", "clipclique", ["inliers.d_comp=0.2"], 30), ("demo", "clipclique", ["inliers.d_comp=0.3"], 30),
        ("demo", "clipclique", ["inliers.d_comp=0.4"], 30)]
    assert len(settings) == 12
    assert settings[0].out == tmp_path / "out" / "demo" / "clipclique+inliers.d_comp=0.2+max_frames=30"


def test_a_plans_run_inputs_are_the_options_of_clipclique_loc_run(tmp_path: Path):
    from clipclique.benchmark.plan import read_plan, runs

    path = tmp_path / "plan.toml"
    path.write_text('scenes = ["demo"]\nmap = "m.map.npz"\nsame_place = true\nwindow = 3\nodometry = "groundtruth"\n'
                    'odometry_drift = 2\nmin_score = 0.3\nlabels = "lvis"\nstrict_detections = true\n')
    (settings,) = runs(read_plan(path), tmp_path / "out", None, record=False)
    assert (settings.map_path, settings.same_place, settings.window, settings.window_step, settings.odometry,
            settings.odometry_drift, settings.min_score, settings.labels, settings.strict_detections) == (
        Path("m.map.npz"), True, 3, 1, "groundtruth", 2.0, 0.3, "lvis", True)
