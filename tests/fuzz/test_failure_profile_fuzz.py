"""Hostile results.json files for `tools/scene_stats.py --results`: one clear line naming the file, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from clipclique.benchmark.scene_stats import main
from clipclique.localization.results import ALL_STAGES, RESULTS_FORMAT, RESULTS_VERSION


def document(frames: list) -> dict:
    """A results.json of the demo (its table's fields only) with these frames."""
    summary = {key: 0.0 for key in ("frames", "precision", "recall", "te_median_m", "re_median_deg", "success@1",
                                    "success@3", "success@5", "time_ms_median", "te_mean_m", "te_p90_m",
                                    "re_mean_deg", "localized")}
    run = {"sequence": "demo", "method_title": "CLIP-Clique", "detector": {"name": "simulated", "simulated": True},
           "encoder": None, "notes": [], "map": "no/such/map.npz"}
    return {"format": RESULTS_FORMAT, "version": RESULTS_VERSION, "run": run,
            "summary": summary | {"success_within_m": {"1": 0.5}, "stage_ms_median": dict.fromkeys(ALL_STAGES, 1.0)},
            "frames": frames}


def frame(index: object = 0, error: object = 0.3, success: object = None) -> dict:
    return {"index": index, "timestamp": 1.0, "hypotheses": [{"translation_error_m": error}],
            "evaluation": {"success": {"1": True} if success is None else success}}


CASES = {
    "not-json": b"{'format': 1",
    "nul": b"\0\0\0",
    "latin1": b'{"format": "\xe9"}',
    "a-list": b"[1, 2]",
    "deep": b"[" * 100_000 + b"]" * 100_000,
    "other-format": json.dumps({"format": "something else"}).encode(),
    "no-frames": json.dumps({k: v for k, v in document([]).items() if k != "frames"}).encode(),
    "frames-an-object": json.dumps(document({"0": frame()})).encode(),  # type: ignore[arg-type]
    "frame-without-index": json.dumps(document([{k: v for k, v in frame().items() if k != "index"}])).encode(),
    "index-a-string": json.dumps(document([frame(index="0")])).encode(),
    "index-a-float": json.dumps(document([frame(index=1.5)])).encode(),
    "error-a-string": json.dumps(document([frame(error="0.3 m")])).encode(),
    "success-a-number": json.dumps(document([frame(success=1)])).encode(),
    "hypotheses-an-object": json.dumps(document([frame() | {"hypotheses": {"rank": 1}}])).encode(),
}
OUT_OF_RANGE = {"index-past-the-end": 4, "index-negative": -1, "index-huge": 2**70}


def run(path: Path, data: Path, capsys) -> str:
    with pytest.raises(SystemExit) as exit:
        main(["--results", str(path), "--data-root", str(data)])
    error = capsys.readouterr().err.strip()
    assert exit.value.code == 2 and len(error.splitlines()) == 1 and "Traceback" not in error, error
    return error


@pytest.mark.parametrize("name", CASES)
def test_a_hostile_results_file_is_one_line_naming_it(name, tmp_path, capsys):
    path = tmp_path / "results.json"
    path.write_bytes(CASES[name])
    assert str(path) in run(path, tmp_path, capsys)


def test_a_folder_or_a_missing_file_is_one_line(tmp_path, capsys):
    assert str(tmp_path) in run(tmp_path, tmp_path, capsys)
    assert "missing.json" in run(tmp_path / "missing.json", tmp_path, capsys)


def test_frames_outside_the_sequence_are_refused_and_a_good_file_reads(demo_data, tmp_path, capsys):
    data = demo_data("demo", frames=4)
    path = tmp_path / "results.json"
    for name, index in OUT_OF_RANGE.items():
        path.write_text(json.dumps(document([frame(), frame(index=index)])))
        assert f"frame index {index} is not a frame of demo (0 to 3)" in run(path, data, capsys), name
    path.write_text(json.dumps(document([frame(0, 0.3), frame(1, 1.0), frame(2, None), frame(3, 5.0)])))
    assert main(["--results", str(path), "--data-root", str(data)]) == 0
    text = capsys.readouterr().out
    assert "| within 0.5 m | 1 (real 1,771) |" in text
    assert "| more than 2 m off | 2 (real 199) |" in text  # 5 m, and an error of None
    assert "| runs | 1 | 104 |" in text
