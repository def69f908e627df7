"""clipclique.benchmark.window's `--spans`: each span the step multiframe.window.span_step makes of it at the measured
frames' interval, exclusive of --step; the table shows span and step; `--view` scores only its newest frames."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from clipclique.benchmark import window as bench
from clipclique.benchmark.suite import CachedFrame, CachedSequence, view_of
from clipclique.config import make_config
from clipclique.multiframe.window import WindowConfig, span_step
from clipclique.types import Ellipsoids, Map, Observations, Pose


def test_each_span_is_the_step_span_step_gives():
    at_30_hz = np.arange(900) / 30.0
    # K = 10: 1 s -> 1 / (9 / 30) = 3.3 -> 3 frames, 3 s -> 10, 6 s -> 20; K = 5 over 6 s -> 45 (REAL_SCENES.md's)
    assert bench.spacings(10, None, [1.0, 3.0, 6.0], at_30_hz) == [(1.0, 3), (3.0, 10), (6.0, 20)]
    assert bench.spacings(5, None, [6.0], at_30_hz) == [(6.0, 45)]
    for size in (2, 5, 10):
        for span in (0.5, 1.0, 3.0, 5.5):
            assert bench.spacings(size, None, [span], at_30_hz) == [(span, span_step(span, size, at_30_hz))]
    assert bench.spacings(1, None, [3.0], at_30_hz) == [(None, 1)]  # one frame: no span
    assert bench.spacings(5, 4, None, at_30_hz) == [(None, 4)]
    assert bench.spacings(5, None, None, at_30_hz) == [(None, 1)]
    every_3rd = at_30_hz[::3]  # 10 Hz frames: the same 3 s span is a third of the step
    assert bench.spacings(10, None, [3.0], every_3rd) == [(3.0, 3)]


def test_the_spans_are_timed_on_the_measured_frames():
    timestamps = 100.0 + np.arange(90) / 30.0
    run = SimpleNamespace(sequence=SimpleNamespace(trajectory=lambda: (timestamps, [None] * 90)))
    frames = [CachedFrame(i, None, None) for i in range(0, 90, 3)]
    sequence = CachedSequence("s", None, frames, {}, {}, run)
    assert bench.frame_times(sequence) == pytest.approx(timestamps[::3])


def test_spans_and_step_exclude_each_other_and_the_table_shows_both():
    with pytest.raises(SystemExit):
        bench.parse_args(["demo_sparse", "--step", "2", "--spans", "3"])
    args = bench.parse_args(["demo_sparse", "--spans", "1", "3"])
    assert args.spans == [1.0, 3.0] and args.step is None
    figures = {f"within_{t:g}m": 0.5 for t in (0.05, 0.1, 0.25, 0.5, 1, 2, 5)}
    rows = [{"scene": "s", "config": "SH", "K": 1, "S": 1, "span_s": None, "drift_percent": 0.0, **figures},
            {"scene": "s", "config": "SH", "K": 10, "S": 10, "span_s": 3.0, "drift_percent": 0.0, **figures},
            {"scene": "s", "config": "SH", "K": 10, "S": 10, "span_s": 3.0, "drift_percent": 1.0, **figures}]
    lines = bench.table(rows).splitlines()
    assert lines[0].startswith("| scene | similarity | K | span | S | exact odometry")
    assert lines[2:] == ["| s | SH | 1 | - | - | 50.0 / 50.0 | 50.0 / 50.0 |",
                         "| s | SH | 10 | 3 s | 10 | 50.0 / 50.0 | 50.0 / 50.0 |"]


def test_a_view_scores_only_its_newest_frames():
    count = 8
    centers = np.stack([np.arange(count, dtype=float), np.zeros(count), np.full(count, 3.0)], axis=1)
    shapes = (np.full((count, 3), 0.2), np.tile(np.eye(3), (count, 1, 1)))
    map = Map(Ellipsoids(centers, *shapes), np.arange(count) % 3, ["cup", "book", "chair"],
              [f"object {i}" for i in range(count)], np.arange(10, 10 + count))

    def seen(*ids: int) -> Observations:
        index = np.array(ids) - 10
        return Observations(map.ellipsoids.subset(index), map.class_ids[index], None, np.array(ids),
                            np.arange(len(ids)))

    views = [(10, 11), (10, 11, 12), tuple(range(10, 18)), (12, 13, 14, 15), (10,)]
    frames = [CachedFrame(i, seen(*ids), Pose.identity()) for i, ids in enumerate(views)]
    sequence = CachedSequence("s", map, frames, {}, {}, None)
    config = make_config("clipclique", overrides=["similarity.alpha=0"])
    expected = {"sparse": 2, "busy": 1, "few": 2, "all": 5}
    assert [view_of(f.observations, map) for f in frames] == ["few", "sparse", "busy", "sparse", "few"]
    for view, scored in expected.items():
        figures = bench.window_success(sequence, config, WindowConfig(size=3, step=1), 0.0, 0, view=view)
        assert figures["frames"] == scored
