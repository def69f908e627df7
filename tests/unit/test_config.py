"""Settings: ranges beside the fields, every tunable constant reachable, earlier keys still accepted."""

from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from clipclique.config import ConfigError, FitParams, LocalizationConfig, ObservationParams, flat, make_config
from clipclique.outcomes import CapHit
from clipclique.pipeline import index_map, localize
from clipclique.sim.synthetic import synthetic_map, synthetic_query

# config.json as written before settings moved beside their fields (clipclique defaults)
EARLIER_CONFIG_JSON = """{"method": "clipclique", "graph": {"d_adj": 0.8, "max_degree": 64, "walk_length": 3,
"xview_walks": 100, "xview_seed": 0}, "similarity": {"descriptor": "fused", "alpha": 0.7, "class_weight": 0.3,
"lookalike_weight": 0.6}, "matching": {"strategy": "adaptive", "k": 3, "top_m_fraction": 0.25, "min_similarity": 0.0},
"inliers": {"method": "cliques", "d_comp": 0.3, "partial_slack": 1.5, "max_slack": 0.8, "slack_min_deficit": 0.2,
"min_clique_size": 3, "max_cliques": 100000, "time_limit_s": 1.0, "ransac_iterations": 1000, "inlier_threshold": 0.5,
"seed": 0, "verification": "overlap", "iou_threshold": 0.3, "rerank": "none"}, "pose": {"weights": "both",
"min_conditioning": 0.05}, "top_n": 5, "success_threshold_m": 1.0, "min_confidence": 0.0, "confidence_model": ""}"""

# the constants that were out of reach of --set, with their values then
NEWLY_REACHABLE = {
    "matching.max_candidates": 20_000, "inliers.max_pairs": 2_000_000,
    "verification.depth_tolerance": 0.5, "verification.missed_weight": 0.25,
    "verification.min_visible_pixels": 1500, "verification.explained_iou": 0.1,
    "observations.min_mask_pixels": 100, "observations.erode_px": 2, "observations.max_depth": 8.0,
    "observations.border_px": 8, "observations.max_border_fraction": 0.5,
    "observations.fit.outlier_neighbors": 20, "observations.fit.outlier_std_ratio": 2.0,
    "observations.fit.min_points": 30, "observations.fit.min_axis": 0.01, "observations.fit.max_points": 5000,
}


def _flatten(tree: dict, prefix: str = "") -> dict:
    return {k: v for key, value in tree.items()
            for k, v in (_flatten(value, f"{prefix}{key}.") if isinstance(value, dict)
                         else {f"{prefix}{key}": value}).items()}


# defaults moved on purpose since that config.json was written (clipclique/benchmark/accuracy_levers.py measured them)
MOVED_DEFAULTS = {"inliers.rerank": "verification"}


def test_an_earlier_config_json_and_its_keys_are_accepted_with_unchanged_defaults(tmp_path):
    earlier = json.loads(EARLIER_CONFIG_JSON)
    path = tmp_path / "config.json"
    path.write_text(EARLIER_CONFIG_JSON)
    as_then = make_config("clipclique", overrides=["inliers.rerank='none'"])
    assert make_config("clipclique", path) == as_then
    now = flat(make_config("clipclique"))
    assert {key: now[key] for key in _flatten(earlier)} == _flatten(earlier) | MOVED_DEFAULTS  # the rest as it was
    assert {key: now[key] for key in NEWLY_REACHABLE} == NEWLY_REACHABLE
    changed = make_config("clipclique", overrides=[f"{key}={value!r}" for key, value in _flatten(earlier).items()])
    assert changed == as_then  # every earlier --set spelling still parses


def test_a_written_config_json_repeats_the_run(tmp_path):
    config = make_config("sh", overrides=["inliers.max_pairs=1000", "observations.fit.max_points=800"])
    path = tmp_path / "config.json"
    path.write_text(json.dumps(config.to_dict()))
    assert make_config("clipclique", path) == config


@pytest.mark.parametrize("text, message", [
    ("[1, 2]", "holds a JSON object, not a list"),
    ('{"inliers": {"d_comp": "far"}}', "inliers.d_comp = 'far' should be a float"),
    ('{"inliers": {"nope": 1}}', "unknown config key 'inliers.nope'"),
    ("{", "not valid JSON"),
])
def test_a_bad_config_json_is_one_line_naming_it(tmp_path, text, message):
    path = tmp_path / "config.json"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as error:
        make_config("clipclique", path)
    assert str(path) in str(error.value) and "\n" not in str(error.value)


def _bounded(config: LocalizationConfig) -> dict[str, tuple[float, float]]:
    """Every setting's range, read from the fields' metadata."""
    def walk(tree, prefix=""):
        for spec in dataclasses.fields(tree):
            value = getattr(tree, spec.name)
            if dataclasses.is_dataclass(value):
                yield from walk(value, f"{prefix}{spec.name}.")
            elif "range" in spec.metadata:
                yield f"{prefix}{spec.name}", spec.metadata["range"]
    return dict(walk(config))


def test_every_number_has_a_range_and_is_refused_outside_it():
    config = make_config("clipclique")
    bounded = _bounded(config)
    numbers = {key for key, value in flat(config).items()
               if isinstance(value, (int, float)) and not isinstance(value, bool)}
    assert numbers == set(bounded) >= set(NEWLY_REACHABLE)
    for key, (low, high) in bounded.items():
        value = flat(config)[key]
        assert low <= value <= high, key
        step = 1 if isinstance(value, int) else max(1e-3, abs(high) * 1e-3)
        for outside in (low - step, high + step):
            outside = int(outside) if isinstance(value, int) else float(outside)
            with pytest.raises(ConfigError, match=f"{key} = .*must be within"):
                make_config("clipclique", overrides={key: outside})
    with pytest.raises(ConfigError, match="finite"):
        make_config("clipclique", overrides={"verification.depth_tolerance": math.inf})


def test_a_frozen_section_is_replaced_not_mutated():
    config = make_config("clipclique", overrides=["observations.fit.min_points=40", "observations.max_depth=5"])
    assert config.observations.fit == FitParams(min_points=40, max_points=5000)
    assert config.observations.max_depth == 5.0 and config.observations.erode_px == 2
    assert ObservationParams().fit.min_points == 30 and make_config().observations.max_depth == 8.0


def test_the_newly_reachable_settings_reach_the_pipeline():
    map = synthetic_map(np.random.default_rng(0), num_landmarks=60)
    observations, _ = synthetic_query(map, np.random.default_rng(1))

    def run(*overrides):
        config = make_config("clipclique", overrides=list(overrides))
        return localize(observations, index_map(map, config), config)

    plain = run()
    assert plain.cap_hit is None and len(plain.candidates) > 6
    few = run("matching.max_candidates=6")
    assert few.cap_hit is CapHit.MAX_CANDIDATES and len(few.candidates) == 6
    assert run("inliers.max_pairs=3").cap_hit is CapHit.MAX_PAIRS
    free = run("verification.missed_weight=0")
    checked = [h for h in plain.hypotheses if h.verification is not None]
    assert checked and any(h.verification != f.verification for h, f in zip(plain.hypotheses, free.hypotheses))


def test_the_runner_fits_observations_with_the_configs_parameters(monkeypatch):
    from clipclique.localization import run as runner

    config = make_config("clipclique", overrides=["observations.min_mask_pixels=777"])
    seen = {}

    def extract(frame, detections, params):
        seen["params"] = params
        return SimpleNamespace(observations=None, dropped={})

    monkeypatch.setattr(runner, "extract_observations", extract)
    monkeypatch.setattr(runner, "embed", lambda *args: None)
    fake = SimpleNamespace(config=config, detector=SimpleNamespace(detect=lambda frame: None), encoder=None,
                           truth_descriptions={}, detections_file=None)
    runner.observe(fake, SimpleNamespace())
    assert seen["params"].min_mask_pixels == 777
