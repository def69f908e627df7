"""A user's own recording whose ground truth is too sparse for TUM's 0.02 s association: the map
build and the run name the cause instead of a bare count of skipped objects or a table of `-`."""

from __future__ import annotations

import numpy as np
from test_annotate import rounded_depth
from test_tum import NAME, T0, write_sequence
from typer.testing import CliRunner

from localization.cli import app as loc_app
from mapping.cli import app as map_app

RUNNER = CliRunner()


def two_hertz(folder) -> None:
    """groundtruth.txt at 2 Hz: no colour image (0.1 s apart from T0 + 0.0013) has a pose within 0.02 s."""
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    lines += [f"{T0 - 0.05 + 0.5 * k:.4f} 1.0 2.0 3.0 0 0 0 1" for k in range(4)]
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")


def test_sparse_ground_truth_is_named_by_build_and_run(tmp_path, monkeypatch):
    folder = write_sequence(tmp_path)
    rounded_depth(folder)
    monkeypatch.chdir(tmp_path)
    args = ["--data-root", str(tmp_path)]
    built = RUNNER.invoke(map_app, ["build", NAME, "--encoder", "none", "--no-rrd", *args])  # 100 Hz: fine
    assert built.exit_code == 0, built.output
    assert "note:" not in built.output
    two_hertz(folder)
    cause = (f"3 of 3 frames have no ground-truth pose: {folder / 'groundtruth.txt'} has no pose within 0.02 s of "
             "their colour image (its poses are 0.5 s apart: record poses at 50 Hz or more, or write one per colour "
             "image with its timestamp)")
    refused = RUNNER.invoke(map_app, ["build", NAME, "--encoder", "none", "--no-rrd", "--out", "sparse.map.npz", *args])
    assert refused.exit_code == 2
    assert cause in " ".join(refused.output.split()), refused.output  # not only "fewer than 30 points"
    ran = RUNNER.invoke(loc_app, ["run", NAME, "--no-rrd", *args])
    assert ran.exit_code == 0, ran.output
    assert f"note: {cause}; those frames cannot be scored" in " ".join(ran.output.split())
    assert "Top-1" in ran.output  # the table still prints, its success columns `-`, with the reason above


def test_ground_truth_that_ends_before_the_images_says_so(tmp_path):
    from clipclique.datasets import open_sequence

    folder = write_sequence(tmp_path, annotations=False)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    (folder / "groundtruth.txt").write_text("\n".join(lines[:22]) + "\n")  # 100 Hz, ending at T0 + 0.15
    gap = open_sequence(NAME, tmp_path).missing_poses()
    assert gap.startswith("1 of 3 frames have no ground-truth pose") and "its poses cover" in gap
    assert np.isclose(float(gap.split("the images ")[1].split(" to ")[0]), T0 + 0.0013, atol=1e-3)
