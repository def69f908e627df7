"""What a benchmark runs: scenes x methods x a grid of settings, from the command line or a plan file.

A plan file (`clipclique-bench --plan FILE.toml`; not a `--config`, which sets parameters of one run):

    scenes = ["demo", "demo_tum", "data/scannet/scans/scene*_00"]   # names, folders or globs
    methods = ["clipclique", "sh"]                                   # default ["clipclique"]
    stride = 1                                                       # as clipclique-loc run
    max_frames = 30
    detector = "gt"                                                  # optional, as clipclique-loc run
    encoder = "open_clip:ViT-L-14/openai"                            # optional
    map = "outputs/maps/map_desk.map.npz"                            # optional: every clipclique-loc run input
    same_place = true                                                #   option, by its name (PLAN_KEYS of
    window = 3                                                       #   clipclique.localization.inputs)
    odometry = "groundtruth"
    [grid]                                                           # every combination is one run
    inliers.d_comp = [0.2, 0.3, 0.4]
"""

from __future__ import annotations

import glob
import itertools
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clipclique.config import MAX_CONFIG_BYTES, METHOD_PRESETS, ConfigError, make_config
from clipclique.datasets import is_bag, scene_name
from clipclique.errors import ClipcliqueError
from clipclique.io.outputs import map_file
from clipclique.io.safeio import read_text
from clipclique.localization.inputs import PLAN_KEYS, RunInputs
from clipclique.localization.run import RunSettings

GLOB_CHARACTERS = "*?["
MAX_RUNS = 100_000  # a grid beyond this is a typo, not a benchmark


class PlanError(ClipcliqueError):
    """A plan (file or options) that cannot be run."""


@dataclass
class Plan:
    scenes: list[str]
    methods: list[str] = field(default_factory=lambda: ["clipclique"])
    grid: dict[str, list[str]] = field(default_factory=dict)  # dotted key -> values, as --set writes them
    stride: int = 1
    max_frames: int | None = None
    detector: str | None = None
    encoder: str | None = None
    inputs: RunInputs = RunInputs()  # the options shared with clipclique-loc run (--map, --window, ...)
    source: str = "command line"  # the plan file, for the errors found when its runs are made


FIELDS = {"scenes": list, "methods": list, "grid": dict, "stride": int, "max_frames": int, "detector": str,
          "encoder": str} | {key: kind for key, (kind, _) in PLAN_KEYS.items()}


def parse_grid(items: list[str], source: str = "--grid") -> dict[str, list[str]]:
    """`["inliers.d_comp=0.2,0.3"]` -> {"inliers.d_comp": ["0.2", "0.3"]}."""
    grid: dict[str, list[str]] = {}
    for item in items:
        key, sep, values = item.partition("=")
        parts = [value.strip() for value in values.split(",")]
        if not sep or not key.strip() or not all(parts):
            raise PlanError(f"{source} {item!r}: not KEY=VALUE,VALUE,... (e.g. inliers.d_comp=0.2,0.3)")
        grid[key.strip()] = parts
    return grid


def read_plan(path: Path) -> Plan:
    """A plan file; a wrong name, type or value is one line naming the file and the entry."""
    text = read_text(path, "plan file", PlanError, limit=MAX_CONFIG_BYTES)
    try:
        tree = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as error:
        raise PlanError(f"{path}: not valid TOML: {error}") from None
    unknown = sorted(set(tree) - set(FIELDS))
    if unknown:
        raise PlanError(f"{path}: unknown entry {unknown[0]!r} (known: {', '.join(FIELDS)})")
    for key, value in tree.items():
        kind = FIELDS[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = tree[key] = float(value)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise PlanError(f"{path}: {key} must be a {kind.__name__}, not {type(value).__name__}")
    for key in ("scenes", "methods"):
        if not all(isinstance(item, str) and item for item in tree.get(key, [])):
            raise PlanError(f"{path}: {key} must be a list of non-empty strings")
    if "scenes" not in tree or not tree["scenes"]:
        raise PlanError(f"{path}: no scenes (scenes = [\"demo\", ...])")
    try:
        entries = _flatten_dotted(tree.get("grid", {}))
    except RecursionError:
        raise PlanError(f"{path}: grid nests too deep") from None
    grid = {}
    for key, values in entries.items():
        values = values if isinstance(values, list) else [values]
        if not values or not all(isinstance(v, (str, int, float, bool)) for v in values):
            raise PlanError(f"{path}: grid.{key} must be a value or a non-empty list of numbers, strings or booleans")
        grid[key] = [_toml_value(v) for v in values]
    inputs = RunInputs(**{key: make(tree[key]) for key, (_, make) in PLAN_KEYS.items() if key in tree})
    return Plan(tree["scenes"], tree.get("methods", ["clipclique"]), grid, tree.get("stride", 1),
                tree.get("max_frames"), tree.get("detector"), tree.get("encoder"), inputs, str(path))


def _flatten_dotted(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """`{"inliers": {"d_comp": [..]}}` (TOML's unquoted dotted keys) -> `{"inliers.d_comp": [..]}`."""
    flat: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat |= _flatten_dotted(value, f"{prefix}{key}.")
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _toml_value(value: str | int | float | bool) -> str:
    """A plan value written as on the command line (`--set KEY=VALUE` reads it back as TOML)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def expand_scenes(patterns: list[str], source: str = "command line") -> list[str]:
    """Names, folders and bags as given; a glob becomes the folders and ROS bags it matches (sorted), none is an
    error."""
    scenes: list[str] = []
    for pattern in patterns:
        if any(c in pattern for c in GLOB_CHARACTERS):
            matches = sorted(p for p in glob.glob(pattern) if Path(p).is_dir() or is_bag(Path(p)))
            if not matches:
                raise PlanError(f"{source}: scene pattern {pattern!r} matches no folder or ROS bag")
            scenes += matches
        else:
            scenes.append(pattern)
    return list(dict.fromkeys(scenes))


def runs(plan: Plan, out_root: Path, data_root: Path | None, record: bool) -> list[RunSettings]:
    """One RunSettings per scene x method x grid point, each writing to out_root/<scene>/<run name>/."""
    if plan.stride < 1 or (plan.max_frames is not None and plan.max_frames < 1):
        raise PlanError(f"{plan.source}: stride and max_frames must be at least 1")
    unknown = [m for m in plan.methods if m not in METHOD_PRESETS]
    if unknown or not plan.methods:
        raise PlanError(f"{plan.source}: unknown method {unknown[0] if unknown else '(none)'!r}; "
                        f"choose from {', '.join(METHOD_PRESETS)}")
    scenes = expand_scenes(plan.scenes, plan.source)
    if len(scenes) * len(plan.methods) * math.prod(len(values) for values in plan.grid.values()) > MAX_RUNS:
        raise PlanError(f"{plan.source}: the plan makes more than {MAX_RUNS} runs")
    points = list(itertools.product(*([f"{key}={value}" for value in values] for key, values in plan.grid.items())))
    settings: dict[Path, RunSettings] = {}
    for scene, method, point in itertools.product(scenes, plan.methods, points):
        try:  # a wrong key or value: an error now, before any work
            make_config(method, overrides=list(point))
        except ConfigError as error:
            raise PlanError(f"{plan.source}: grid {' '.join(point)}: {error}") from None
        run = RunSettings(scene, method, overrides=list(point), data_root=data_root, detector=plan.detector,
                          encoder=plan.encoder, stride=plan.stride, max_frames=plan.max_frames, record=record,
                          **plan.inputs.settings())
        run.out = out_root / scene_name(scene) / run.run_name()
        if is_bag(Path(scene)) and run.map_path is None:  # a bag holds no map: the default one, as for every scene
            run.map_path = map_file(scene_name(scene))
        settings.setdefault(run.out, run)
    return list(settings.values())

