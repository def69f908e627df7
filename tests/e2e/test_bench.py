"""The benchmark suite (clipclique.benchmark.suite, clipclique.benchmark.report): a quick run on the demo, and the
report's logic."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clipclique.benchmark import report
from clipclique.benchmark import suite as bench
from clipclique.config import make_config
from clipclique.sim.demo import DEMO_SCENES

ROOT = Path(__file__).resolve().parents[2]

GROUP_LABELS = {group: [v.label for v in bench.variants() if v.group == group]
                for group in ("methods", "fixes", "descriptors", "inliers", "weights", "matching", "alpha")}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory) -> Path:
    """`tools/bench.py --sequences demo --quick` run from an empty folder (so it builds its own demo map)."""
    cwd = tmp_path_factory.mktemp("bench")
    env = os.environ | {"CLIPCLIQUE_DATA": str(ROOT / "data")}
    subprocess.run([sys.executable, str(ROOT / "tools" / "bench.py"), "--sequences", "demo", "--quick", "--out",
                    "report"],
                   cwd=cwd, env=env, check=True, capture_output=True, timeout=300)
    return cwd / "report"


def table_rows(markdown: str, label: str) -> list[list[str]]:
    """Cells of every table row whose first (Table I, alpha) or second (ablations) cell is `label`,
    starting at that cell; a † marks stochastic rows."""
    rows = []
    for line in markdown.splitlines():
        cells = [c.strip().removesuffix(" †") for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and label in cells[:2]:
            rows.append(cells[cells.index(label):])
    return rows


def section(markdown: str, heading: str) -> str:
    return markdown.split(f"## {heading}")[1].split("\n## ")[0]


def test_quick_report_has_every_row_with_numbers(quick_run):
    text = (quick_run / "report.md").read_text()
    tables = {"methods": section(text, "Table I"),
              **dict.fromkeys(("fixes", "descriptors", "inliers", "weights", "matching"),
                                                                    section(text, "Ablations"))}
    for group, table in tables.items():
        for label in GROUP_LABELS[group]:
            rows = table_rows(table, label)
            assert rows, f"no row for {group} / {label}"
            assert 0.0 <= float(rows[0][5]) <= 100.0  # Top-1 [%]
            assert 0.0 <= float(rows[0][1]) <= 1.0  # precision
    alpha = section(text, "Alpha sweep")
    assert [0.0 <= float(table_rows(alpha, label)[0][1]) <= 100.0 for label in GROUP_LABELS["alpha"]] == [True] * 11
    assert "simulated: detector (simulated), CLIP (simulated-clip)" in text
    assert "Quick mode" in text and "Not run: --quick skips it" in text and "checks)." in text


def test_quick_report_matches_its_json(quick_run):
    results = json.loads((quick_run / "results.json").read_text())
    assert results["sequences"]["demo"]["frames"] == bench.QUICK_FRAMES
    records = results["experiments"]["demo"]
    assert [r["label"] for r in records] == [v.label for v in bench.variants()]
    text = (quick_run / "report.md").read_text()
    clipclique = next(r for r in records if r["group"] == "methods" and r["label"] == "CLIP-Clique")
    row = table_rows(text, "CLIP-Clique")[0]
    assert float(row[5]) == pytest.approx(100 * clipclique["summary"]["success@1"], abs=0.05)
    assert float(row[1]) == pytest.approx(clipclique["summary"]["precision"], abs=0.005)
    for record in records:
        assert 0.0 <= record["summary"]["success@1"] <= record["summary"]["success@5"] <= 1.0
        if record["stochastic"]:  # best of three seeds, and the spread spans them
            top1 = [s["success@1"] for s in record["per_seed"]]
            assert record["seeds"] == [0, 1, 2] and record["summary"]["success@1"] == max(top1)
            assert record["spread"]["success@1"] == [min(top1), max(top1)]
    for curve in results["scalability"].values():
        assert [r["landmarks"] > 0 for r in curve["rows"]] == [True] * 3
        assert curve["rows"][0]["landmarks"] < curve["rows"][-1]["landmarks"]


def test_cached_observations_give_the_numbers_clipclique_loc_gives(quick_run):
    from clipclique.localization.run import RunSettings, execute, prepare
    from clipclique.sim.demo import DEMO_SCENES

    settings = RunSettings("demo", map_path=quick_run.parent / "outputs" / "maps" / "demo.map.npz",
                           data_root=ROOT / "data",
                           stride=DEMO_SCENES["demo"].num_frames // bench.QUICK_FRAMES, max_frames=bench.QUICK_FRAMES,
                           record=False)
    direct = execute(prepare(settings)).summary()
    records = json.loads((quick_run / "results.json").read_text())["experiments"]["demo"]
    cached = next(r for r in records if r["label"] == "CLIP-Clique")["summary"]
    for column in ("success@1", "success@3", "success@5", "precision", "recall", "te_median_m", "re_median_deg"):
        assert cached[column] == pytest.approx(direct[column]), column


def test_quick_plots_are_real_pngs(quick_run):
    for name in ("methods.png", "alpha.png", "scalability.png"):
        with Image.open(quick_run / name) as image:
            assert image.format == "PNG" and image.width > 300 and image.height > 200
            assert np.asarray(image.convert("L")).std() > 5  # not a blank canvas


def test_curve_recovers_a_quadratic_through_the_papers_point():
    rows = [{"landmarks": n, "median_ms": 1000.0 * (n / 410) ** 2, "median_total_ms": 1000.0 * (n / 410) ** 2}
            for n in (50, 100, 200, 500, 1000)]
    fitted = bench.curve(rows)
    assert fitted["exponent_total"] == pytest.approx(2.0)
    assert fitted["landmarks_at_1s"] == pytest.approx(410, rel=1e-6)
    assert fitted["ms_at_paper_size"] == pytest.approx(1000.0)
    assert report.global_claims({"scalability": {"scene": fitted}})[0][2] == "agrees"
    slow = bench.curve([r | {"median_total_ms": 0.01 * r["landmarks"]} for r in rows])
    assert slow["landmarks_at_1s"] is None and slow["exponent_total"] == pytest.approx(1.0)
    assert report.global_claims({"scalability": {"scene": slow}})[0][2].startswith("**disagrees**")


def test_claims_say_plainly_when_ours_disagree():
    def record(group: str, label: str, top1: float, descriptor: str | None = None, te: float = 0.3) -> dict:
        summary = {"success@1": top1, "te_median_m": te,
                   "similarity_true_mean": 0.3, "similarity_true_p90": {"clip": 0.41, "sh": 0.2}.get(descriptor, 0.5)}
        return {"group": group, "label": label, "summary": summary,
                "overrides": {"similarity.descriptor": descriptor} if descriptor else {}}

    results = {"sequences": {"s": {"frames": 10}}, "experiments": {"s": [
        record("methods", "CLIP-Clique", 0.5), record("methods", "SH", 0.7),
        record("inliers", "Maximal cliques", 0.8), record("inliers", "RANSAC", 0.6),
        record("weights", "w_sim * w_com", 0.5, te=0.2), record("weights", "none", 0.5, te=0.3),
        record("descriptors", "SH", 0.1, "sh"), record("descriptors", "CLIP", 0.2, "clip"),
        record("descriptors", "SH + CLIP", 0.3, "fused"),
    ]}}
    verdicts = {claim: verdict for claim, _, verdict in report.sequence_claims(results, "s")}
    assert verdicts["CLIP-Clique beats every baseline"] == "**disagrees**"
    assert verdicts["Maximal cliques beat RANSAC and PROSAC"] == "agrees"
    assert verdicts["Pose weights help (w_sim * w_com best)"] == "ties"
    assert verdicts["Pose weights lower the error (median TE, w_sim * w_com vs none)"] == "agrees"
    assert verdicts["Adaptive matching is best"] == "–"  # the group did not run
    assert verdicts["SH + CLIP beats either descriptor alone"] == "agrees"
    # SH 0.2
    assert verdicts["True pairs: CLIP similarity reaches about 0.4 where SH reaches about 0.8"] == "**disagrees**"


def test_real_sequences_need_their_map(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for folder in ("data/scannet/scans/scene0001_00", "data/scannet/scans/scene0002_00",
                   "data/tum/rgbd_dataset_freiburg2_desk"):
        (tmp_path / folder).mkdir(parents=True)
    (tmp_path / "outputs" / "maps").mkdir(parents=True)
    (tmp_path / "outputs" / "maps" / "scene0002_00.map.npz").touch()
    names, skipped = bench.available_sequences(Path("data"))
    assert names == [*DEMO_SCENES, "scene0002_00"]
    assert [s.split(":")[0] for s in skipped] == ["scene0001_00", "rgbd_dataset_freiburg2_desk"]
    with pytest.raises(SystemExit) as exit_info:
        bench.main(["--sequences", "scene0001_00", "--quick", "--out", "report"])
    assert exit_info.value.code == 2
    assert "no map of scene0001_00; build it with `clipclique-map build scene0001_00`" in capsys.readouterr().err
    assert not (tmp_path / "report").exists()


def test_a_failed_demo_map_build_is_one_line(tmp_path, monkeypatch, capsys):
    from clipclique.errors import DatasetError

    def unwritable(*args, **kwargs):
        raise DatasetError("data/demo: cannot write the demo scene there (Permission denied)")

    monkeypatch.chdir(tmp_path)
    # the suite builds demo maps through the engine
    monkeypatch.setattr("clipclique.benchmark.engine.run_build", unwritable)
    with pytest.raises(SystemExit) as exit_info:
        bench.main(["--sequences", "demo", "--quick", "--out", "report"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines() == [  # the progress display ends with an empty line
        "bench: error: data/demo: cannot write the demo scene there (Permission denied)"]
    assert not (tmp_path / "report").exists()


def test_each_ablation_changes_one_part_of_clipclique_and_seeds_only_vary_stochastic_ones():
    def flat(tree: dict, prefix: str = "") -> dict:
        return {k: v for key, value in tree.items()
                for k, v in (flat(value, f"{prefix}{key}.") if isinstance(value, dict)
                             else {f"{prefix}{key}": value}).items()}

    for variant in bench.variants():
        if variant.group == "methods":
            continue
        default = flat(make_config(variant.method).to_dict())  # verification / rerank rows change a baseline
        changed = {k for k, v in flat(variant.config().to_dict()).items() if v != default[k]}
        assert changed <= {key for key, _ in variant.overrides}, variant
    stochastic = {v.label for v in bench.variants() if v.stochastic}
    baselines = ("X-View", "SH", "CLIP-Loc")
    assert stochastic == {*baselines, "RANSAC", "PROSAC", *(f"{b}, centre distances" for b in baselines),
                          *(f"{b}, re-ranked" for b in baselines)}


def test_without_clip_the_clip_rows_say_why_and_tables_stay_aligned(quick_run, monkeypatch):
    monkeypatch.chdir(quick_run.parent)  # its outputs/maps holds the demo map the quick run built
    sequence = bench.cache_sequence("demo", ROOT / "data", 3, lambda total: None)
    for frame in sequence.frames:
        frame.observations.image_embeddings = None
    records = [bench.run_variant(sequence, variant, lambda: None) for variant in bench.variants()]
    skipped = {r["label"] for r in records if "skipped" in r}
    assert skipped == {"CLIP-Loc", "CLIP", *GROUP_LABELS["alpha"], "CLIP-Loc, centre distances", "CLIP-Loc, re-ranked"}
    fused = next(r for r in records if r["label"] == "CLIP-Clique")
    assert fused["notes"] and "SH only" in fused["notes"][0]
    sh = next(r for r in records if r["label"] == "SH" and r["group"] == "descriptors")
    assert fused["summary"]["success@1"] == sh["summary"]["success@1"]  # fused without CLIP is SH
    results = {"sequences": {"demo": sequence.description}, "experiments": {"demo": records}}
    table_one = report.table_one(results)
    assert "| CLIP-Loc † | not run: no CLIP embeddings" in table_one
    for text in (table_one, report.ablations(results), report.alpha_section(results, plotted=False),
                 report.verification_section(results, plotted=False)):
        for table in tables_of(text):
            assert len({line.count("|") for line in table}) == 1, table


def tables_of(markdown: str) -> list[list[str]]:
    """Runs of consecutive table lines."""
    tables: list[list[str]] = [[]]
    for line in markdown.splitlines():
        if line.startswith("|"):
            tables[-1].append(line)
        elif tables[-1]:
            tables.append([])
    return [t for t in tables if t]


@pytest.mark.models
def test_gpu_stages_time_every_stage_with_random_weight_models(quick_run, monkeypatch):
    """The GPU section's code path, on the CPU with the smallest models of the same families."""
    from clipclique.localization.run import RunSettings, prepare

    monkeypatch.chdir(quick_run.parent)
    run = prepare(RunSettings("demo", data_root=ROOT / "data", max_frames=2, record=False))
    timed = bench.gpu_stages(run, frames=1, device="cpu", warmup=1, clip_model="ViT-B-32",
                             yolo_config="yolov8n-seg.yaml")
    assert timed["frames"] == 1 and set(timed["stage_ms"]) == {"detector", "observations", "encoder"}
    assert all(ms > 0 for ms in timed["stage_ms"].values())
    results = {"gpu": {"ran": True, "sequence": "demo", **timed}}
    results["gpu"]["stage_ms"]["algorithm"] = 0.5
    text = report.gpu_section(results)
    assert "ViT-B-32 (random weights)" in text and "frames per second" in text


def test_bench_loc_user_mistakes_are_one_line(tmp_path):
    for args, expected in ((["nosuch"], "unknown scene 'nosuch'"), (["--repeat", "0"], "--repeat"),
                           (["--method", "x"], "--method")):
        done = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_loc.py"), *args], cwd=tmp_path,
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and expected in done.stderr and "Traceback" not in done.stderr, done.stderr


def test_readme_figures_are_the_committed_reports():
    """The README's generated figures are those of docs/benchmark/results.json (`make docs` writes both)."""
    committed = json.loads((ROOT / "docs" / "benchmark" / "results.json").read_text())
    readme = (ROOT / "README.md").read_text()
    assert report.update_readme(readme, report.readme_figures(committed)) == readme
    assert "<!-- figures:benchmark -->\nMeasured by `make docs`" in readme


def test_update_readme_replaces_only_its_regions():
    text = "a\n<!-- figures:benchmark -->\nold\n<!-- /figures -->\nb\n"
    assert (report.update_readme(text, {"benchmark": "new\n"})
            == "a\n<!-- figures:benchmark -->\nnew\n<!-- /figures -->\nb\n")
    with pytest.raises(ValueError, match="do not match"):
        report.update_readme("no region\n", {"benchmark": "new\n"})
    other = text + "<!-- figures:scene_stats_demo_desk -->\n| x |\n<!-- /figures -->\n"  # another generator's region
    assert report.update_readme(other, {"benchmark": "new\n"}).endswith(
        "<!-- figures:scene_stats_demo_desk -->\n| x |\n<!-- /figures -->\n")


def test_make_docs_regenerates_every_readme_region(tmp_path):
    """Each generated region of the README has a `make docs` step that writes it."""
    import shutil

    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    (tmp_path / ".venv").mkdir()
    for stamp in (".installed-core", ".installed"):
        (tmp_path / ".venv" / stamp).touch()
    steps = subprocess.run(["make", "-n", "docs"], cwd=tmp_path, capture_output=True, text=True, check=True).stdout
    names = [name for _, name, _, _ in report.README_REGION.findall((ROOT / "README.md").read_text())]
    scene_names = [name for _, name, _, _ in report.README_REGION.findall((ROOT / "docs" / "scenes.md").read_text())]
    scenes = [name.removeprefix("scene_stats_") for name in scene_names]
    assert names == ["benchmark"] and scene_names == [f"scene_stats_{scene}" for scene in scenes] and scenes
    assert "tools/bench.py --docs" in steps
    assert f"tools/scene_stats.py {' '.join(scenes)} --readme docs/scenes.md" in steps


@pytest.mark.slow
def test_committed_report_reproduces_table_one_on_the_demo(tmp_path, monkeypatch):
    """A fresh run of Table I on the demo gives the committed report's accuracy (timings are not
    reproducible and not compared). Fails when the algorithm changed without `make docs`."""
    committed = json.loads((ROOT / "docs" / "benchmark" / "results.json").read_text())
    monkeypatch.chdir(tmp_path)  # builds its own demo map, as `make docs` does from a clean outputs/
    bench.ensure_map("demo", ROOT / "data")
    sequence = bench.cache_sequence("demo", ROOT / "data", None, lambda total: None)
    assert sequence.description["frames"] == committed["sequences"]["demo"]["frames"]
    expected = {r["label"]: r for r in committed["experiments"]["demo"] if r["group"] == "methods"}
    for variant in (v for v in bench.variants() if v.group == "methods"):
        fresh = bench.run_variant(sequence, variant, lambda: None)
        for column in ("success@1", "success@3", "success@5", "precision", "recall", "te_median_m"):
            assert fresh["summary"][column] == pytest.approx(expected[variant.label]["summary"][column]), \
                (variant.label, column)


def test_quick_report_compares_verifications_and_reranking(quick_run):
    text = section((quick_run / "report.md").read_text(), "Verification in the image, re-ranking and confidence")
    for title in ("X-View", "SH", "CLIP-Loc"):
        for variant in ("projected overlap", "centre distances"):
            rows = table_rows(text, f"{title}, {variant}")
            assert rows and 0.0 <= float(rows[0][5]) <= 100.0, (title, variant)
    reranked = [line for line in text.splitlines() if line.startswith("| demo |") and line.count("|") == 6]
    assert [line.split("|")[2].strip() for line in reranked] == ["X-View", "SH", "CLIP-Loc", "CLIP-Clique"]
    assert "Not measured: a held-out measurement needs two sequences or more." in text


def test_calibration_section_states_the_goals():
    measured = {"sequences": ["a", "b"], "hypotheses": 10, "ece": 0.07, "ece_answers": 0.04,
                "acceptance": {"threshold": 0.8, "accepted": 5, "accepted_correct": 5, "frames_with_correct": 8,
                               "share_of_reachable": 0.625,
                               "at_min_confidence": {"accepted": 4, "precision": 1.0, "share_of_reachable": 0.5}},
                "by_scene": {"a": {"ece": 0.07, "acceptance": {"frames_with_correct": 8, "accepted_correct": 5,
                                                               "share_of_reachable": 0.625, "threshold": 0.8}}},
                "by_method": {"sh": {"frames_with_correct": 8, "accepted_correct": 5, "share_of_reachable": 0.625,
                                     "threshold": 0.8}}}
    text = report.calibration_text(measured, plotted=True)
    assert "**0.070** over hypotheses" in text and "goal < 0.05: **not met**" in text
    assert "5 of the 8 frames" in text and "**62.5%**; goal 80%: **not met**" in text
    assert "| a | 0.070 | 8 | 5 (62.5%) | 0.80 |" in text and "| sh | 8 | 5 (62.5%) | 0.80 |" in text
    assert "![Reliability diagram on held-out scenes](reliability.png)" in text
