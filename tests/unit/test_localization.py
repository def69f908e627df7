"""Result files and CLI behaviour that need no dataset: TUM lines, JSON without NaN, user errors."""

from __future__ import annotations

import gc
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rich.text import Text
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from clipclique.datasets.tum import tum_line
from clipclique.errors import ClipcliqueError
from clipclique.localization.cli import app, imports_kept
from clipclique.localization.results import ALL_STAGES, json_safe, read_results
from clipclique.localization.run import choose_encoder, read_ahead
from clipclique.localization.tables import results_table, run_banner
from clipclique.sim.poses import random_rotation
from clipclique.types import Ellipsoids, Map, Pose

RUNNER = CliRunner()


def test_tum_line_round_trips_the_pose():
    pose = Pose(random_rotation(np.random.default_rng(3)), np.array([1.5, -2.25, 0.125]))
    fields = [float(v) for v in tum_line(1305031102.175304, pose).split()]
    assert len(fields) == 8
    assert fields[0] == pytest.approx(1305031102.175304, abs=1e-6)
    np.testing.assert_allclose(fields[1:4], pose.translation, atol=1e-6)
    np.testing.assert_allclose(Rotation.from_quat(fields[4:]).as_matrix(), pose.rotation, atol=1e-5)
    quarter_turn = Pose(Rotation.from_euler("z", 90, degrees=True).as_matrix(), np.zeros(3))
    assert tum_line(7, quarter_turn).split()[4:] == ["0.000000", "0.000000", "0.707107", "0.707107"]


def test_finite_replaces_nan_and_numpy_scalars():
    tree = {"a": np.float64("nan"), "b": [np.int64(3), np.float32(0.5), float("inf")], 4: np.bool_(True)}
    cleaned = json_safe(tree)
    assert cleaned == {"a": None, "b": [3, 0.5, None], "4": True}
    json.dumps(cleaned, allow_nan=False)


def test_read_results_rejects_other_files(tmp_path):
    (tmp_path / "x.json").write_text('{"format": "something else"}')
    with pytest.raises(Exception, match="not a version 1"):
        read_results(tmp_path / "x.json")


def _document(method: str, success: float, simulated: bool) -> dict:
    summary = {"frames": 10.0, "precision": 0.9, "recall": 0.5, "te_median_m": None, "re_median_deg": 2.0,
               "success@1": success, "success@3": success, "success@5": success, "time_ms_median": 3.0,
               "success_within_m": {"0.25": None, "0.5": success, "1": success, "2": success}, "te_mean_m": None,
               "te_p90_m": None, "re_mean_deg": 2.0, "localized": 1.0}
    return {"run": {"sequence": "demo", "method_title": method, "notes": ["a note"],
                    "detector": {"name": "simulated", "simulated": simulated}, "encoder": None},
            "summary": summary}


def test_tables_show_the_papers_columns_and_flag_simulated_parts():
    table = results_table([_document("CLIP-Clique", 0.8, True), _document("SH", 0.25, True)])
    headers = [Text.from_markup(c.header).plain for c in table.columns]
    assert headers[2:] == ["Prec.", "Rec.", "TE [m]", "RE [°]", "Top-1", "Top-3", "Top-5", "ms"]
    top1 = list(table.columns[6].cells)
    assert top1 == ["80.0", "25.0"] and list(table.columns[4].cells) == ["-", "-"]
    assert run_banner(_document("SH", 0.2, True)).splitlines() == [
        "detector: simulated (SIMULATED)", "encoder: none", "note: a note"]


def test_cli_help_and_missing_map(tmp_path, monkeypatch):
    assert "--method" in RUNNER.invoke(app, ["run", "--help"]).output
    result = RUNNER.invoke(app, ["run", "demo", "--map", str(tmp_path / "none.map.npz"), "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert f"--map {tmp_path / 'none.map.npz'}: no such map file" in " ".join(result.output.split())
    assert not (tmp_path / "results.json").exists()
    monkeypatch.chdir(tmp_path)  # no outputs/maps here
    default = RUNNER.invoke(app, ["run", "demo", "--data-root", str(tmp_path), "--out", str(tmp_path)])
    assert default.exit_code == 2 and "no map of demo yet; build it with" in " ".join(default.output.split())
    assert "clipclique-map build demo" in default.output
    bad = RUNNER.invoke(app, ["run", "demo", "--set", "inliers.nope=1", "--map", str(tmp_path / "m.npz")])
    assert bad.exit_code == 2 and "inliers.nope" in bad.output


def test_an_unwritable_out_folder_is_a_user_error(monkeypatch, tmp_path):
    """Found before the frames are localized, as one line naming --out (it was a traceback after the run)."""
    import clipclique.localization.run as runner
    from clipclique.localization.run import RunSettings

    monkeypatch.setattr(runner, "prepare",
                        lambda settings: SimpleNamespace(sequence=SimpleNamespace(name="demo"), settings=settings))
    monkeypatch.setattr(runner, "execute", lambda *args: pytest.fail("ran frames into a folder it cannot write"))
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    with pytest.raises(ClipcliqueError, match="--out .*a-file/out"):
        runner.run_and_save(RunSettings("demo", out=blocker / "out", record=False))


def test_an_interrupted_run_leaves_no_folder_it_made(monkeypatch, tmp_path):
    """Ctrl-C (or an error) during the frames: the folders the run created are gone, others stay."""
    import clipclique.localization.run as runner
    from clipclique.localization.run import RunSettings

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "prepare",
                        lambda settings: SimpleNamespace(sequence=SimpleNamespace(name="demo"), settings=settings))
    monkeypatch.setattr(runner, "execute", interrupted)
    (tmp_path / "kept").mkdir()
    for out in (tmp_path / "new" / "run", tmp_path / "kept"):
        with pytest.raises(KeyboardInterrupt):
            runner.run_and_save(RunSettings("demo", out=out, record=False))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"]


def _map(encoder: str, embeddings: bool) -> Map:
    text = np.eye(3, 512, dtype=np.float32) if embeddings else None
    return Map(Ellipsoids(np.zeros((3, 3)), np.ones((3, 3)), np.tile(np.eye(3), (3, 1, 1))), np.zeros(3, int),
               ["chair"], ["a chair"] * 3, np.arange(1, 4), text, encoder)


def test_encoder_choice_follows_the_map():
    notes: list[str] = []
    assert choose_encoder(None, _map("simulated-clip", True), notes).name == "simulated-clip"
    assert choose_encoder(None, _map("none", False), notes) is None and not notes
    assert choose_encoder(None, _map("open_clip:ViT-B-32/no-such-tag", True), notes) is None
    assert notes and "not available" in notes[0]
    assert choose_encoder("none", _map("simulated-clip", True), notes) is None
    with pytest.raises(ClipcliqueError, match="not comparable"):
        choose_encoder("simulated", _map("open_clip:ViT-L-14/openai", True), notes)


def test_a_frame_without_ground_truth_has_no_success_verdict_in_the_results():
    from clipclique.config import make_config
    from clipclique.localization.results import frame_record
    from clipclique.localization.run import FrameOutcome
    from clipclique.metrics import evaluate_frame
    from clipclique.pipeline import index_map, localize
    from clipclique.sim.synthetic import synthetic_map, synthetic_query

    rng = np.random.default_rng(3)
    map = synthetic_map(rng)
    observations, truth = synthetic_query(map, rng)
    config = make_config("clipclique")
    result = localize(observations, index_map(map, config), config)
    records = {}
    for gt_pose in (truth, None):
        evaluation = evaluate_frame(result, observations, map, gt_pose, config, 0)
        outcome = FrameOutcome(0, 0.0, "0", gt_pose, len(observations), {}, result, evaluation, {})
        records[gt_pose is None] = frame_record(outcome)["evaluation"]
    assert records[False]["success"] == {"1": True, "3": True, "5": True}
    assert records[True]["success"] is None and records[True]["translation_error_m"] is None


def test_run_folders_are_named_by_what_changes_the_results(tmp_path):
    from clipclique.localization.run import RunSettings

    assert RunSettings("demo").out_dir("demo") == Path("outputs/loc/demo/clipclique")
    assert RunSettings("fr2", "sh").out_dir("rgbd_dataset_freiburg2_desk").parts[-2:] == (
        "rgbd_dataset_freiburg2_desk", "sh")  # the resolved name, not the alias typed
    ablation = RunSettings("demo", overrides=["inliers.d_comp=0.4", "top_n=3"], stride=2, detector="gt")
    assert ablation.run_name() == "clipclique+inliers.d_comp=0.4+top_n=3+detector=gt+stride=2"
    config = tmp_path / "my.toml"
    config.write_text("[inliers]\nd_comp = 0.4\n")
    first = RunSettings("demo", config_file=config).run_name()
    config.write_text("[inliers]\nd_comp = 0.5\n")
    assert first.startswith("clipclique+my-") and RunSettings("demo", config_file=config).run_name() != first
    odd = RunSettings("demo", encoder="open_clip:ViT-L-14/openai",
                      overrides=["confidence_model=x" + "9" * 200]).run_name()
    assert "/" not in odd and len(odd) == 100
    assert RunSettings("demo", out=tmp_path / "here").out_dir("demo") == tmp_path / "here"


def test_compare_marks_runs_that_differ_and_fits_80_columns():
    from rich.console import Console

    from clipclique.localization.tables import print_documents

    def document(sequence: str, method: str, changed: dict) -> dict:
        base = _document(method, 0.7, True)
        base["run"] |= {"sequence": sequence, "changed": changed, "map": f"outputs/maps/{sequence}.map.npz",
                        "stride": 1, "max_frames": None}
        base["summary"]["stage_ms_median"] = dict.fromkeys(ALL_STAGES, 123.4)
        return base

    documents = [document("demo_tum", "CLIP-Clique", {}),
                 document("demo_tum", "CLIP-Clique", {"inliers.d_comp": 0.6, "matching.strategy": "knn"}),
                 document("demo_tum", "CLIP-Clique", {"inliers.d_comp": 0.6, "matching.strategy": "knn"}),
                 document("demo_tum", "CLIP-Loc", {"similarity.alpha": 0.0})]
    console = Console(width=80, record=True)
    print_documents(console, documents)
    text = console.export_text()
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80 and "…" not in text
    assert "demo_tum" in lines  # the sequence heads its tables
    rows = [line for line in lines if line.startswith("CLIP-")]
    assert [row.split("  ")[0].strip() for row in rows[:4]] == [
        "CLIP-Clique", "CLIP-Clique (a)", "CLIP-Clique (a)", "CLIP-Loc (b)"]
    assert "(a) inliers.d_comp=0.6 matching.strategy=knn" in lines and "(b) similarity.alpha=0.0" in lines


def test_a_map_of_another_recording_is_refused_unless_said_to_be_of_the_same_place():
    from clipclique.localization.run import RunSettings, check_map_source

    map = _map("simulated-clip", True)
    map.provenance = {"source": {"name": "demo"}}
    notes: list[str] = []
    with pytest.raises(ClipcliqueError, match="a map of demo, not of demo_tum; if demo_tum is another recording of the "
                                              "place demo shows, pass --same-place"):
        check_map_source(map, Path("demo.map.npz"), "demo_tum", RunSettings("demo_tum"), notes)
    check_map_source(map, Path("demo.map.npz"), "demo_tum", RunSettings("demo_tum", same_place=True), notes)
    assert notes == ["the map is of demo, another recording of this place (--same-place): poses are in its frame, "
                     "and demo_tum's ground truth scores them only if it shares that frame"]


def test_version_short_help_and_no_developer_notes():
    from importlib.metadata import version

    from clipclique.benchmark.cli import app as bench_app
    from clipclique.mapping.cli import app as map_app

    for tool, name in ((app, "clipclique-loc"), (map_app, "clipclique-map")):
        printed = RUNNER.invoke(tool, ["--version"])
        assert printed.exit_code == 0 and printed.output == f"{name} {version('clipclique')}\n"
        short, long = RUNNER.invoke(tool, ["-h"]), RUNNER.invoke(tool, ["--help"])
        assert short.exit_code == 0 and short.output == long.output
        assert "Heavy modules" not in long.output and "imported" not in long.output
    assert "--quiet" in RUNNER.invoke(app, ["run", "-h"]).output
    printed = RUNNER.invoke(bench_app, ["--version"])
    assert printed.exit_code == 0 and printed.output == f"clipclique-bench {version('clipclique')}\n"


def test_ctrl_c_is_one_line_and_exit_130(monkeypatch):
    import clipclique.localization.run as runner

    def interrupted(settings, progress):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "run_and_save", interrupted)
    result = RUNNER.invoke(app, ["run", "demo", "--no-rrd"])
    assert result.exit_code == 130
    assert result.stderr.strip() == "clipclique-loc: interrupted"  # one line, no traceback


class Frames:
    """A sequence whose frame 5 is unreadable, recording which frames were read."""

    def __init__(self) -> None:
        self.read: list[int] = []

    def __getitem__(self, i: int) -> str:
        self.read.append(i)
        if i == 5:
            raise ClipcliqueError("frame 5: unreadable image")
        return f"frame {i}"


def test_frames_read_ahead_come_in_order_errors_where_reached_and_closing_stops_reading():
    frames = Frames()
    ahead = read_ahead(frames, range(0, 12, 2))
    assert [next(ahead), next(ahead)] == ["frame 0", "frame 2"]
    ahead.close()
    assert {0, 2} <= set(frames.read) <= {0, 2, 4, 6}  # two frames ahead of the caller at most, none after closing
    seen = []
    with pytest.raises(ClipcliqueError, match="frame 5"):
        for frame in read_ahead(Frames(), range(3, 9)):
            seen.append(frame)
    assert seen == ["frame 3", "frame 4"]  # the frames before the unreadable one, then its error
    assert list(read_ahead(frames, range(0))) == [] and list(read_ahead(frames, range(7, 8))) == ["frame 7"]


def test_the_run_commands_imports_are_frozen_and_collection_resumes_after_them():
    """`clipclique-loc run` imports without collecting and freezes what its imports made; a failed import
    (a broken install) must not leave the run without garbage collection."""
    gc.unfreeze()
    try:
        with pytest.raises(ImportError), imports_kept():
            assert not gc.isenabled()
            import clipclique_no_such_module  # noqa: F401
        assert gc.isenabled()
        assert gc.get_freeze_count() > 1000  # this process's objects, frozen
    finally:
        gc.unfreeze()
