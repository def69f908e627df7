"""The terminal tables as a user reads them: `clipclique-loc compare` into a pipe and on an 80-column
terminal, with the longest real TUM sequence names."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from rich.console import Console

from clipclique.errors import ClipcliqueError
from clipclique.localization.results import ALL_STAGES, RESULTS_FORMAT, RESULTS_VERSION, read_results
from clipclique.localization.tables import print_documents

LOC = Path(sys.executable).with_name("clipclique-loc")
LONGEST = "rgbd_dataset_freiburg3_long_office_household"  # the longest name of a real TUM sequence we read
WITHIN = ("0.05", "0.1", "0.25", "0.5", "1", "2", "5")
ALL_WITHIN = ["5.0", "25.0", "50.0", "75.0", "90.5", "100.0", "100.0"]  # the accuracy table's cells at WITHIN


def results(sequence: str, method_title: str, changed: dict, max_frames: int | None = None) -> dict:
    """A results document as `clipclique-loc run` writes it, with wide numbers in every column."""
    summary = {"frames": 2488, "precision": 0.875, "recall": 0.5, "te_median_m": 12.345, "re_median_deg": 123.4,
               "success@1": 0.905, "success@3": 0.95, "success@5": 1.0, "time_ms_median": 1234.5,
               "success_within_m": dict(zip(WITHIN, (0.05, 0.25, 0.5, 0.75, 0.905, 1.0, 1.0))), "te_mean_m": 12.345,
               "te_p90_m": 99.99, "re_mean_deg": 123.4, "localized": 0.955,
               "failures": {"few_observations": 100, "no_clique": 12},
               "stage_ms_median": dict.fromkeys(ALL_STAGES, 1234.5)}
    run = {"sequence": sequence, "method_title": method_title, "notes": [], "changed": changed,
           "detector": {"name": "annotations", "simulated": False},
           "encoder": {"name": "simulated-clip", "simulated": True},
           "map": f"outputs/maps/{sequence}.map.npz", "stride": 1, "max_frames": max_frames}
    return {"format": RESULTS_FORMAT, "version": RESULTS_VERSION, "run": run, "summary": summary, "frames": []}


def write_runs(tmp_path: Path) -> list[Path]:
    runs = [results(LONGEST, "CLIP-Clique", {}), results(LONGEST, "CLIP-Clique (paper)", {"inliers.d_comp": 0.6}),
            results("rgbd_dataset_freiburg2_desk", "CLIP-Loc", {"success_threshold_m": 0.5}),
            results("rgbd_dataset_freiburg2_desk", "CLIP-Loc", {}, max_frames=20)]
    paths = []
    for i, document in enumerate(runs):
        (tmp_path / str(i)).mkdir()
        paths.append(tmp_path / str(i) / "results.json")
        paths[-1].write_text(json.dumps(document))
    return paths


def check_whole(text: str, within_longest: list[str] = ALL_WITHIN) -> list[str]:
    """Every cell whole: no `…`, every row's numbers (the accuracy rows' success cells: `within_longest` for the
    longest name's, every threshold for the desk's) and both sequence names in full."""
    assert "…" not in text
    lines = text.splitlines()
    assert LONGEST in lines and "rgbd_dataset_freiburg2_desk" in lines  # each on a line of its own
    rows = [line.split() for line in lines if line.startswith("CLIP-") and "without a pose" not in line]
    assert len(rows) == 12  # a results, an accuracy and a stage row per run
    for row in rows[:2] + rows[6:8]:  # results rows: frames, precision, recall, TE, RE, top-1/3/5, ms
        assert row[-9:] == ["2488", "0.88", "0.50", "12.35", "123.4", "90.5", "95.0", "100.0", "1234.5"]
    for row, within in zip(rows[2:4] + rows[8:10], [within_longest] * 2 + [ALL_WITHIN] * 2):
        assert row[-4 - len(within):] == ["95.5", *within, "12.35", "99.99", "123.4"]  # posed, success, TE, RE
    for row in rows[4:6] + rows[10:]:  # stage rows: 9 stages
        assert row[-9:] == ["1234"] * 9
    return lines


def test_compare_into_a_pipe_keeps_long_names_and_numbers_whole(tmp_path):
    paths = write_runs(tmp_path)
    for columns in ("80", "200"):
        done = subprocess.run([str(LOC), "compare", *map(str, paths)], capture_output=True, text=True, timeout=120,
                              env=os.environ | {"COLUMNS": columns})
        assert done.returncode == 0, done.stderr
        lines = check_whole(done.stdout)
        assert lines[-3:] == ["(a) inliers.d_comp=0.6", "(b) success_threshold_m=0.5", "(c) max_frames=20"]
        assert "CLIP-Loc (c): 112 of 2488 frames without a pose: 100 few observations, 12 no clique" in lines
        # not "within 1 m"
        assert "within the run's success threshold (0.5, 1 m: see the marks)" in " ".join(done.stdout.split())


def test_an_80_column_terminal_fits_the_tables_of_the_longest_names(tmp_path):
    documents = [json.loads(p.read_text()) for p in write_runs(tmp_path)]
    console = Console(width=80, force_terminal=True, record=True)
    print_documents(console, documents)
    text = console.export_text()
    lines = check_whole(text, ALL_WITHIN[1:-1])  # 0.1 to 2 m: beside the longest name 0.05 and 5 m do not fit
    assert max(len(line) for line in lines) <= 80
    wide = Console(width=120, force_terminal=True, record=True)
    print_documents(wide, documents)
    assert max(len(line) for line in check_whole(wide.export_text())) <= 120  # every threshold


def test_a_run_from_before_a_threshold_reads_and_shows_none_there(tmp_path):
    path = write_runs(tmp_path)[0]
    document = json.loads(path.read_text())
    document["summary"]["success_within_m"] = {"0.25": 0.5, "0.5": 0.75, "1": 0.905, "2": 1.0}  # 0.25 to 2 m only
    path.write_text(json.dumps(document))
    console = Console(width=200, force_terminal=True, record=True)
    print_documents(console, [read_results(path)])
    accuracy = [line.split() for line in console.export_text().splitlines() if line.startswith("CLIP-")][1]
    assert accuracy[-11:] == ["95.5", "-", "-", "50.0", "75.0", "90.5", "100.0", "-", "12.35", "99.99", "123.4"]
    document["summary"]["success_within_m"]["1"] = "90%"
    path.write_text(json.dumps(document))
    with pytest.raises(ClipcliqueError, match=r"summary.success_within_m.1 has the wrong type \(str\)"):
        read_results(path)


def test_compare_takes_a_folder_of_runs_and_ties_each_detector_to_its_runs(tmp_path):
    (tmp_path / "loc").mkdir()
    paths = write_runs(tmp_path / "loc")  # loc/0 ... loc/3, each a run folder
    document = json.loads(paths[3].read_text())
    document["run"]["detector"] = {"name": "yolo:yolov8x-seg.pt", "simulated": False}
    paths[3].write_text(json.dumps(document))
    done = subprocess.run([str(LOC), "compare", str(tmp_path / "loc")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    lines = check_whole(done.stdout)
    assert lines[:6] == [f"runs: {LONGEST} CLIP-Clique, {LONGEST} CLIP-Clique (paper) (a), "
                         "rgbd_dataset_freiburg2_desk CLIP-Loc (b)", "detector: annotations",
                         "encoder: simulated-clip (SIMULATED)", "runs: rgbd_dataset_freiburg2_desk CLIP-Loc (c)",
                         "detector: yolo:yolov8x-seg.pt", "encoder: simulated-clip (SIMULATED)"]
    empty = subprocess.run([str(LOC), "compare", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert empty.returncode == 2 and f"{tmp_path}: holds no results.json, nor run folders that do" in empty.stderr
