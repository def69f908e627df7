"""clipclique.benchmark.failure_profile: a frame's row, the failure runs, the table beside the real desk's."""

from __future__ import annotations

from clipclique.benchmark.failure_profile import ROWS, FrameHits, failure_runs, frame_row, table


def record(*errors: float | None, ground_truth: bool = True) -> dict:
    """A results.json frame whose ranked hypotheses have these translation errors."""
    return {"hypotheses": [{"translation_error_m": e} for e in errors],
            "evaluation": {"success": {"1": False} if ground_truth else None}}


def test_each_frame_falls_in_one_row_in_the_issues_order():
    assert frame_row(record(0.49, 3.0)) == ROWS[0]
    assert frame_row(record(0.5, 3.0)) == ROWS[1]  # 0.5 is off
    assert frame_row(record(1.99)) == ROWS[1] and frame_row(record(2.0)) == ROWS[2]
    assert frame_row(record(3.0, 2.5, 1.0, 0.7, 0.3)) == ROWS[3]  # the right pose at rank 5, below a wrong one
    assert frame_row(record(3.0, 2.5, 1.0, 0.7, 0.6, 0.1)) == ROWS[2]  # rank 6 is not the top 5
    assert frame_row(record(1.0, None)) == ROWS[1]  # an error the run could not compute is no right pose
    assert frame_row(record()) == ROWS[4]
    assert frame_row(record(0.1, ground_truth=False)) is None


def hits(rows: str, seconds: float = 1 / 30) -> list[FrameHits]:
    """Frames at 30 Hz, one per letter: o within 0.5 m, x 0.5-2 m off, - no pose."""
    kinds = {"o": ROWS[0], "x": ROWS[1], "-": ROWS[4]}
    return [FrameHits(kinds[c], 10 if c == "o" else 4, 8 if c == "o" else 3, 6 if c == "o" else 1, i * seconds)
            for i, c in enumerate(rows)]


def runs(frames: list[FrameHits]) -> list[tuple[int, float]]:
    return [(n, round(s, 9)) for n, s in failure_runs(frames)]


def test_failure_runs_are_consecutive_frames_off_or_without_a_pose():
    assert runs(hits("ooxx-oxoooxxx")) == [(3, 0.1), (1, round(1 / 30, 9)), (3, 0.1)]
    assert runs(hits("xoo")) == [(1, round(1 / 30, 9))] and runs(hits("ooo")) == []
    assert runs(hits("xx-", seconds=0.5)) == [(3, 1.5)]  # every 15th frame: half a second each


def test_table_puts_each_figure_beside_the_real_one():
    frames = hits("o" * 40 + "x" * 31 + "o" * 9 + "-" * 2)
    text = table(frames)
    assert "| within 0.5 m | 49 (real 1,771) | 10 (real 12) | 8 (real 10) | 6 (real 6) |" in text
    assert ("| 0.5-2 m off (right place, imprecise pose) | 31 (real 216) | 4 (real 7) | 3 (real 4) | 1 (real 2) |"
            in text)
    assert "| no pose | 2 (real 6) | - (real -) | - (real -) | - (real -) |" in text
    assert "| runs | 2 | 104 |" in text and "| median run | 16.5 frames | 1 frame |" in text
    assert "| frames in runs of 1 s or longer | 31 | 245 |" in text  # 31 frames at 30 Hz: 1.03 s; 2 frames are not
    assert "| longest run | 31 frames (1.0 s) | 164 frames (5.5 s) |" in text
