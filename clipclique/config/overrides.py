"""A configuration built up and checked: a method's preset, then a TOML file or a run's config.json (so a run
can be repeated), then `key=value` overrides (`inliers.d_comp=0.4`), each key's name, type and range checked.

Every key an earlier version wrote is still accepted (tests/unit/test_config.py holds one such config.json).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any, Literal, NamedTuple, get_args, get_origin, get_type_hints

from clipclique.config.presets import METHOD_PRESETS
from clipclique.config.schema import ConfigError, LocalizationConfig
from clipclique.io.safeio import read_json, read_text

MAX_CONFIG_BYTES = 1 << 20


def make_config(
    method: str = "clipclique",
    file: Path | None = None,
    overrides: dict[str, Any] | list[str] | None = None,
) -> LocalizationConfig:
    """Preset for `method`, then the TOML or JSON `file`, then `overrides` (dotted keys)."""
    if method not in METHOD_PRESETS:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHOD_PRESETS)}")
    config = LocalizationConfig(method=method)
    apply_overrides(config, METHOD_PRESETS[method], source=f"method preset {method}")
    if file is not None:
        apply_overrides(config, _flatten(load_file(file)), source=str(file))
    if overrides:
        if isinstance(overrides, list):
            overrides = parse_assignments(overrides)
        apply_overrides(config, overrides, source="command line")
    return config


def changed_by_overrides(method: str, file: Path | None, overrides: list[str]) -> dict[str, Any]:
    """The settings `overrides` change over the method's preset and the file, by dotted key in the order given,
    with their final values: `inliers.d_comp = 0.4` and `inliers.d_comp=0.40` are one change, and one that
    repeats the value already set is none (what names a run's folder)."""
    before = flat(make_config(method, file))
    after = flat(make_config(method, file, overrides))
    return {key: after[key] for key in parse_assignments(overrides) if after[key] != before[key]}


def load_file(path: Path) -> dict[str, Any]:
    """A config file: a results folder's config.json (by its suffix), else TOML read as strict UTF-8
    (tomllib's own rule); a ConfigError naming it when it is neither."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        tree = read_json(path, "config file", ConfigError, limit=MAX_CONFIG_BYTES)
        if not isinstance(tree, dict):
            raise ConfigError(f"{path}: a config file holds a JSON object, not a {type(tree).__name__}")
        return tree
    text = read_text(path, "config file", ConfigError, limit=MAX_CONFIG_BYTES)
    try:
        return tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from None


def parse_assignments(items: list[str]) -> dict[str, Any]:
    """`["inliers.d_comp=0.4", "pose.weights=sim"]` -> dotted-key dict (values parsed as TOML)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"override {item!r} is not KEY=VALUE (e.g. inliers.d_comp=0.4)")
        try:
            out[key.strip()] = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = raw.strip()  # a bare word such as ransac
    return out


def apply_overrides(config: LocalizationConfig, values: dict[str, Any], source: str) -> None:
    """Set dotted keys on `config` in place, checking names and types (a frozen section is replaced)."""
    for dotted, value in values.items():
        _set(config, dotted.split("."), value, dotted, source)
    try:
        validate(config)
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None


def _set(target: Any, path: list[str], value: Any, dotted: str, source: str) -> Any:
    """`target` with the setting at `path` changed: itself when mutable, a replaced copy when frozen."""
    part, rest = path[0], path[1:]
    if not dataclasses.is_dataclass(target) or part not in _field_names(target):
        raise ConfigError(f"{source}: unknown config {'section' if rest else 'key'} {dotted!r}")
    current = getattr(target, part)
    if rest:
        new = _set(current, rest, value, dotted, source)
    elif dataclasses.is_dataclass(current):
        raise ConfigError(f"{source}: {dotted!r} is a section, set one of its keys")
    else:
        new = _coerce(value, current, dotted, source)
    if target.__dataclass_params__.frozen:
        return dataclasses.replace(target, **{part: new})
    setattr(target, part, new)
    return target


def validate(config: LocalizationConfig) -> None:
    """ConfigError naming the first key whose value is out of its range or not one of its choices."""
    if config.method not in METHOD_PRESETS:
        raise ConfigError(f"method = {config.method!r}; choose one of {', '.join(METHOD_PRESETS)} (with --method)")
    for dotted, setting in _settings(config).items():
        value = setting.value
        choices = get_args(setting.type) if get_origin(setting.type) is Literal else ()
        if choices and value not in choices:
            raise ConfigError(f"{dotted} = {value!r}; choose one of {', '.join(choices)}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{dotted} = {value}; must be a finite number")
        if setting.range is not None and not setting.range[0] <= value <= setting.range[1]:
            raise ConfigError(f"{dotted} = {value}; must be within [{setting.range[0]}, {setting.range[1]}]")


def flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    """Every setting by its dotted key (`inliers.d_comp`)."""
    return {dotted: setting.value for dotted, setting in _settings(tree, prefix).items()}


class _Setting(NamedTuple):
    type: Any  # the field's annotation, resolved (a Literal gives the choices)
    range: tuple[float, float] | None  # from `ranged`
    value: Any


def _settings(tree: Any, prefix: str = "") -> dict[str, _Setting]:
    """Every setting of a config (or a section) by its dotted key."""
    out: dict[str, _Setting] = {}
    hints = get_type_hints(type(tree))
    for spec in dataclasses.fields(tree):
        value = getattr(tree, spec.name)
        if dataclasses.is_dataclass(value):
            out.update(_settings(value, f"{prefix}{spec.name}."))
        else:
            out[f"{prefix}{spec.name}"] = _Setting(hints[spec.name], spec.metadata.get("range"), value)
    return out


def _field_names(obj: Any) -> set[str]:
    return {f.name for f in dataclasses.fields(obj)}


def _coerce(value: Any, current: Any, dotted: str, source: str) -> Any:
    if isinstance(current, bool):
        if isinstance(value, bool):
            return value
    elif isinstance(current, int) and isinstance(value, int) and not isinstance(value, bool):
        return value
    elif isinstance(current, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    elif isinstance(current, str) and isinstance(value, str):
        return value
    raise ConfigError(f"{source}: {dotted} = {value!r} should be a {type(current).__name__}")


def _flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out
