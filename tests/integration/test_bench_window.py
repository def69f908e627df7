"""clipclique.benchmark.window (tools/bench_window.py) on a few frames of demo_desk: K = 1 is the single-frame result, a
window helps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clipclique.benchmark.suite import cache_sequence, ensure_map
from clipclique.benchmark.window import table, window_success
from clipclique.config import make_config
from clipclique.multiframe.window import WindowConfig
from clipclique.pipeline import index_map, localize
from clipclique.pose.distance import pose_errors

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def desk():
    ensure_map("demo_desk", ROOT / "data")
    return cache_sequence("demo_desk", ROOT / "data", 40, lambda total: None)


def test_a_window_of_one_is_the_single_frame_result_and_a_longer_one_helps(desk):
    config = make_config("clipclique", overrides=["similarity.alpha=0"])
    index = index_map(desk.map, config)
    single = []
    for frame in desk.frames:
        result = localize(frame.observations, index, config)
        single.append(bool(result.hypotheses) and pose_errors(result.hypotheses[0].pose, frame.gt_pose)[0] < 1.0)
    one = window_success(desk, config, WindowConfig(size=1), 0.0, 0)
    assert one["within_1m"] == pytest.approx(np.mean(single))
    five = window_success(desk, config, WindowConfig(size=5), 1.0, 0)
    # Four frames of the 40 or more (five before verification.missed_share_from; the whole sequence ties, 83.3%)
    assert round(len(desk.frames) * (five["within_1m"] - one["within_1m"])) >= 4
    assert five["observations_mean"] > 2 * one["observations_mean"] and five["dropped_frames"] == 0
    rows = [{"scene": "demo_desk", "config": "SH", "K": k, "S": 1, "drift_percent": d, **figures}
            for k, d, figures in ((1, 0.0, one), (5, 1.0, five))]
    assert (f"| demo_desk | SH | 5 | - | {100 * five['within_0.5m']:.1f} / {100 * five['within_1m']:.1f} |"
            in table(rows))
