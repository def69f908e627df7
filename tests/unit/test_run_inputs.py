"""The run options `clipclique-loc run`, `clipclique-bench` and plan files share (clipclique.localization.inputs)."""

from __future__ import annotations

from pathlib import Path

import pytest

from clipclique.errors import ClipcliqueError
from clipclique.localization.inputs import PLAN_KEYS, RunInputs


def test_a_window_span_or_a_step_never_both():
    with pytest.raises(ClipcliqueError, match=r"--window-span 3 and --window-step 1 are mutually exclusive"):
        RunInputs(window=5, window_step=1, window_span=3.0)  # an explicit step of 1 is a step too
    spread = RunInputs(window=5, window_span=3.0).settings()
    assert (spread["window"], spread["window_step"], spread["window_span"]) == (5, 1, 3.0)  # run.with_window_span
    stepped = RunInputs(window=5, window_step=2).settings()
    assert (stepped["window_step"], stepped["window_span"]) == (2, None)
    assert RunInputs().settings()["window_step"] == 1


def test_every_input_is_a_plan_key_and_a_run_setting():
    fields = set(RunInputs.__dataclass_fields__)
    assert set(PLAN_KEYS) == fields
    settings = RunInputs(map=Path("m.map.npz"), min_score=None).settings()
    assert settings["map_path"] == Path("m.map.npz") and settings["min_score"] == 0.0 and "map" not in settings
