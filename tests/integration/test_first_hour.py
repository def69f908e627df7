"""A new user's first hour (issue 23), as they type it: `clipclique-map build` and `clipclique-loc run`
on a shortened demo scene generated on first use."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest
from rich.console import Console
from typer.testing import CliRunner

from clipclique.localization.cli import app as loc_app
from clipclique.localization.tables import print_frames
from clipclique.mapping.cli import app as map_app
from clipclique.sim import demo

pytestmark = pytest.mark.slow
RUNNER = CliRunner()
FRAMES = 6


@pytest.fixture(scope="module")
def first_use(tmp_path_factory) -> tuple[Path, str]:
    """A fresh working folder where `clipclique-map build demo` generates the (shortened) demo; its output."""
    root = tmp_path_factory.mktemp("first-hour")
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(root)
        patch.setitem(demo.DEMO_SCENES, "demo", dataclasses.replace(demo.DEMO_SCENES["demo"], num_frames=FRAMES))
        patch.setenv("CLIPCLIQUE_DATA", str(root / "data"))
        built = RUNNER.invoke(map_app, ["build", "demo"])
        assert built.exit_code == 0, built.output
    return root, built.output


@pytest.fixture
def in_first_use(first_use, monkeypatch) -> Path:
    root, _ = first_use
    monkeypatch.chdir(root)
    monkeypatch.setenv("CLIPCLIQUE_DATA", str(root / "data"))
    return root


def test_the_first_build_says_it_generates_the_scene(first_use, in_first_use):
    root, output = first_use
    assert (f"generating the demo scene into {root / 'data' / 'demo' / 'demo'} (first use only"
            in output.replace("\n", ""))
    again = RUNNER.invoke(map_app, ["build", "demo", "--no-rrd", "--out", "again.map.npz"])
    assert again.exit_code == 0 and "generating" not in again.output  # generated once


def test_encoder_auto_says_it_looks_for_clip_weights(in_first_use):
    done = RUNNER.invoke(map_app, ["build", "demo", "--encoder", "auto", "--no-rrd", "--out", "auto.map.npz"])
    assert done.exit_code == 0, done.output
    assert "--encoder auto: looking for CLIP weights" in done.output


def test_verbose_lines_name_each_frame_once_in_plain_words(in_first_use):
    done = RUNNER.invoke(loc_app, ["run", "demo", "-v", "--no-rrd"])
    assert done.exit_code == 0, done.output
    frames = [line for line in done.output.splitlines() if line.startswith("frame ")]
    assert len(frames) == FRAMES
    assert all(re.fullmatch(r"frame \d+: \d+ observations?, (TE \d+\.\d\d m|no pose: .+)", line)
               for line in frames), frames
    console = Console(width=200, record=True)
    frame = {"index": 3, "name": "1305031102.175304", "observations": 1, "failure": "fewer than 3 observations (1)",
             "evaluation": {"translation_error_m": None}}
    print_frames(console, {"frames": [frame]})
    assert console.export_text().strip() == ("frame 3 (image 1305031102.175304): 1 observation, no pose: fewer than 3 "
                                             "observations (1)")


def test_set_spellings_of_one_change_share_a_folder_and_the_presets_value_renames_nothing(in_first_use):
    folders = []
    for given in (["inliers.d_comp = 0.4"], ["inliers.d_comp=0.40"], ["inliers.d_comp=0.3"],
                  ["inliers.d_comp=0.3", "top_n=5", "graph.d_adj=0.8"]):
        done = RUNNER.invoke(loc_app, ["run", "demo", "-q", "--no-rrd", *[arg for s in given for arg in ("--set", s)]])
        assert done.exit_code == 0, done.output
        folders.append(re.search(r"results: (\S+)/ ", done.output).group(1))
    assert folders == ["outputs/loc/demo/clipclique+inliers.d_comp=0.4"] * 2 + ["outputs/loc/demo/clipclique"] * 2


def test_the_recordings_description_lists_the_changed_settings_not_a_json_block(in_first_use):
    from clipclique.localization.run import RunSettings, prepare, recording_description

    text = recording_description(prepare(RunSettings("demo", overrides=["inliers.d_comp=0.4"])))
    assert "{" not in text
    assert "- settings changed from the preset: `inliers.d_comp = 0.4`" in text.splitlines()


def test_errors_lead_somewhere_and_read_alike_in_both_tools(in_first_use):
    def error(app, *args: str) -> str:
        done = RUNNER.invoke(app, list(args))
        assert done.exit_code == 2 and "Traceback" not in done.output
        lines = [line for line in done.output.splitlines() if line.strip()]
        assert len(" ".join(lines)) > 0 and "Value error" not in done.output
        return " ".join(done.output.split())

    typo = error(loc_app, "run", "dmeo")
    assert typo.startswith("clipclique-loc: error: unknown scene 'dmeo'") and typo.endswith("did you mean demo?")
    assert "build dmeo" not in typo  # no command that would fail too
    assert error(map_app, "build", "dmeo").startswith("clipclique-map: error: unknown scene 'dmeo'")  # one prefix
    missing = error(loc_app, "run", "demo", "--map", "elsewhere.map.npz")
    assert missing == "clipclique-loc: error: --map elsewhere.map.npz: no such map file"
    method = error(loc_app, "run", "demo", "--method", "clipclque")
    assert method.startswith("clipclique-loc: error: --method clipclque: no such method; did you mean clipclique?")


def test_method_accepts_the_names_the_tables_print(in_first_use):
    for typed, folder in (("CLIP-Clique", "clipclique"), ("CLIP-Clique (paper)", "clipclique-paper"),
                          ("X-View", "xview")):
        done = RUNNER.invoke(loc_app, ["run", "demo", "--method", typed, "-q", "--no-rrd"])
        assert done.exit_code == 0, done.output
        assert f"results: outputs/loc/demo/{folder}/" in done.output


def test_a_run_writes_a_row_per_frame_and_counts_its_failures(in_first_use):
    import csv
    import json
    from collections import Counter

    done = RUNNER.invoke(loc_app, ["run", "demo", "--no-rrd", "--set", "inliers.min_clique_size=4"])
    assert done.exit_code == 0, done.output
    folder = in_first_use / "outputs" / "loc" / "demo" / "clipclique+inliers.min_clique_size=4"
    document = json.loads((folder / "results.json").read_text())
    with open(folder / "frames.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    assert [int(row["index"]) for row in rows] == [frame["index"] for frame in document["frames"]]
    for row, frame in zip(rows, document["frames"]):
        error = frame["evaluation"]["translation_error_m"]
        assert row["translation_error_m"] == ("" if error is None else str(error))
        assert row["within_1m"] == str(int(error is not None and error < 1.0))
        assert (row["localized"] == str(int(frame["failure"] is None))
                and row["failure_kind"] == (frame["failure_kind"] or ""))
    kinds = Counter(frame["failure_kind"] for frame in document["frames"] if frame["failure_kind"])
    assert document["summary"]["failures"] == dict(kinds) and isinstance(document["summary"]["frames"], int)
    assert kinds, "the shortened demo has frames without a pose"  # and the console names why
    reasons = ", ".join(f"{n} {kind.replace('_', ' ')}" for kind, n in kinds.most_common())
    assert f"frames without a pose: {reasons}" in " ".join(done.output.split())
