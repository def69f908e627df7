"""Parameters with the paper's defaults; methods and ablations are configurations of one pipeline.

A configuration is built from a method preset, then optionally a TOML file, then `key=value`
overrides (`inliers.d_comp=0.4`), and written next to every result so a run can be repeated.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from clipclique.errors import ClipcliqueError
from clipclique.safeio import read_text

Descriptor = Literal["fused", "clip", "sh", "xview"]
MatchingStrategy = Literal["adaptive", "knn", "one_to_one"]
InlierMethod = Literal["cliques", "ransac", "prosac"]
PoseWeights = Literal["none", "sim", "com", "both"]
Verification = Literal["overlap", "centers"]
Rerank = Literal["none", "verification", "confidence"]


class ConfigError(ClipcliqueError):
    """A configuration file or override is wrong; the message says which key and why."""


@dataclass
class GraphConfig:
    d_adj: float = 0.8  # metres: landmarks closer than this are neighbours
    max_degree: int = 64  # neighbours kept per node at most (memory bound; real scenes stay under ~30)
    walk_length: int = 3  # Semantic Histogram path length s (nodes per walk)
    xview_walks: int = 100  # X-View: random walks per node
    xview_seed: int = 0


@dataclass
class SimilarityConfig:
    descriptor: Descriptor = "fused"
    alpha: float = 0.7  # S = alpha * S_clip + (1 - alpha) * S_sh
    # Beyond the paper (0 = the paper's literal SH): S_sh <- w * S_class + (1 - w) * S_sh, so an
    # object with no neighbour within d_adj (an empty histogram) still matches by its class.
    class_weight: float = 0.3
    # Beyond the paper (0 = exact labels): weight of a look-alike class (clipclique.lookalikes) in the
    # class term and the query's Semantic Histograms, so a cup detected as "bottle" still finds cups.
    lookalike_weight: float = 0.6


@dataclass
class MatchingConfig:
    strategy: MatchingStrategy = "adaptive"
    k: int = 3  # kNN
    top_m_fraction: float = 0.25  # adaptive: M = fraction of the landmarks
    min_similarity: float = 0.0  # candidates at or below this are dropped


@dataclass
class InlierConfig:
    method: InlierMethod = "cliques"
    d_comp: float = 0.3  # metres: rigid distance test of the compatibility graph
    # Beyond the paper (0 = the literal test): a candidate whose observed ellipsoid is smaller than
    # its landmark (a part of a couch, a bed, a counter) has its centre displaced by up to the
    # difference of their semi-axes; the pair test is widened by this fraction of each candidate's
    # largest semi-axis deficit (when it is at least slack_min_deficit), at most max_slack metres per candidate.
    partial_slack: float = 1.5
    max_slack: float = 0.8  # metres
    slack_min_deficit: float = 0.2  # metres (tools/sweep_slack.py: README "Beyond the paper")
    min_clique_size: int = 3  # fewer cannot fix a 6-DoF pose
    max_cliques: int = 100_000  # enumeration stops here and says so
    time_limit_s: float = 1.0  # enumeration stops here and says so
    ransac_iterations: int = 1000
    inlier_threshold: float = 0.5  # metres: RANSAC/PROSAC centre residual to count as inlier (centers)
    seed: int = 0
    verification: Verification = "overlap"  # RANSAC/PROSAC: projected box overlap (the paper) or 3D centre distance
    iou_threshold: float = 0.3  # RANSAC/PROSAC overlap verification: box IoU to count as inlier
    rerank: Rerank = "none"  # reorder every method's hypotheses by image verification or confidence


@dataclass
class PoseConfig:
    weights: PoseWeights = "both"  # w = s_total * w_com ("sim" = s_total only, "com" = w_com only)
    # A correspondence set whose centres are nearly a row (pose.conditioning below this) gives no
    # pose: with 0.1 m centre noise most such poses are over 1 m off (tools/bench_conditioning.py).
    min_conditioning: float = 0.05


@dataclass
class LocalizationConfig:
    method: str = "clipclique"
    graph: GraphConfig = field(default_factory=GraphConfig)
    similarity: SimilarityConfig = field(default_factory=SimilarityConfig)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    inliers: InlierConfig = field(default_factory=InlierConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    top_n: int = 5
    success_threshold_m: float = 1.0
    min_confidence: float = 0.0  # hypotheses less confident are dropped; a frame left without one is not localized
    confidence_model: str = ""  # JSON file of a refitted confidence model ("": the one shipped in the package)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# The paper's Table I: each method is the one pipeline with parts swapped.
# The baselines keep the paper's literal descriptors (no class term, exact labels).
LITERAL = {"similarity.class_weight": 0.0, "similarity.lookalike_weight": 0.0, "inliers.partial_slack": 0.0}

METHOD_PRESETS: dict[str, dict[str, Any]] = {
    "clipclique": {},
    "clipclique-paper": LITERAL,
    "sh": {
        **LITERAL,
        "similarity.descriptor": "sh",
        "matching.strategy": "one_to_one",
        "inliers.method": "ransac",
        "pose.weights": "none",
    },
    "xview": {
        **LITERAL,
        "similarity.descriptor": "xview",
        "matching.strategy": "one_to_one",
        "inliers.method": "ransac",
        "pose.weights": "none",
    },
    "cliploc": {
        **LITERAL,
        "similarity.descriptor": "clip",
        "matching.strategy": "knn",
        "inliers.method": "prosac",
        "pose.weights": "none",
    },
}

METHOD_TITLES = {"clipclique": "CLIP-Clique", "clipclique-paper": "CLIP-Clique (paper)", "sh": "SH", "xview": "X-View", "cliploc": "CLIP-Loc"}


# Bounds that keep every setting meaningful and the work it asks for finite. Semantic Histogram
# walks grow as degree^(s-1) and their codes as C^s: s = 5 is beyond the paper's 3 and safe.
RANGES: dict[str, tuple[float, float]] = {
    "graph.d_adj": (1e-6, 100.0),
    "graph.max_degree": (1, 10_000),
    "graph.walk_length": (1, 5),
    "graph.xview_walks": (1, 10_000),
    "graph.xview_seed": (0, 2**63 - 1),
    "similarity.alpha": (0.0, 1.0),
    "similarity.class_weight": (0.0, 1.0),
    "similarity.lookalike_weight": (0.0, 1.0),
    "matching.k": (1, 1000),
    "matching.top_m_fraction": (1e-6, 1.0),
    "matching.min_similarity": (-1.0, 1.0),
    "inliers.d_comp": (1e-6, 100.0),
    "inliers.partial_slack": (0.0, 100.0),
    "inliers.max_slack": (0.0, 100.0),
    "inliers.slack_min_deficit": (0.0, 100.0),
    "inliers.min_clique_size": (3, 1000),  # fewer than 3 cannot fix a 6-DoF pose
    "inliers.max_cliques": (1, 10_000_000),
    "inliers.time_limit_s": (1e-6, 3600.0),
    "inliers.ransac_iterations": (1, 10_000_000),
    "inliers.inlier_threshold": (1e-6, 100.0),
    "inliers.seed": (0, 2**63 - 1),
    "inliers.iou_threshold": (0.0, 1.0),
    "pose.min_conditioning": (0.0, 1.0),
    "top_n": (1, 1000),
    "success_threshold_m": (1e-6, 1e5),
    "min_confidence": (0.0, 1.0),
}
MAX_CONFIG_BYTES = 1 << 20


def make_config(
    method: str = "clipclique",
    file: Path | None = None,
    overrides: dict[str, Any] | list[str] | None = None,
) -> LocalizationConfig:
    """Preset for `method`, then the TOML `file`, then `overrides` (dotted keys)."""
    if method not in METHOD_PRESETS:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHOD_PRESETS)}")
    config = LocalizationConfig(method=method)
    apply_overrides(config, METHOD_PRESETS[method], source=f"method preset {method}")
    if file is not None:
        apply_overrides(config, _flatten(load_toml(file)), source=str(file))
    if overrides:
        if isinstance(overrides, list):
            overrides = parse_assignments(overrides)
        apply_overrides(config, overrides, source="command line")
    return config


def load_toml(path: Path) -> dict[str, Any]:
    """A TOML config file, read as strict UTF-8 (tomllib's own rule) with a ConfigError naming it otherwise."""
    text = read_text(Path(path), "config file", ConfigError, limit=MAX_CONFIG_BYTES)
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
    """Set dotted keys on `config` in place, checking names and types."""
    for dotted, value in values.items():
        target: Any = config
        *parents, leaf = dotted.split(".")
        for part in parents:
            if not dataclasses.is_dataclass(target) or part not in _field_names(target):
                raise ConfigError(f"{source}: unknown config section {dotted!r}")
            target = getattr(target, part)
        if not dataclasses.is_dataclass(target) or leaf not in _field_names(target):
            raise ConfigError(f"{source}: unknown config key {dotted!r}")
        current = getattr(target, leaf)
        if dataclasses.is_dataclass(current):
            raise ConfigError(f"{source}: {dotted!r} is a section, set one of its keys")
        setattr(target, leaf, _coerce(value, current, dotted, source))
    try:
        validate(config)
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None


def validate(config: LocalizationConfig) -> None:
    """ConfigError naming the first key whose value is out of its range or not one of its choices."""
    allowed = {
        "similarity.descriptor": Descriptor,
        "matching.strategy": MatchingStrategy,
        "inliers.method": InlierMethod,
        "pose.weights": PoseWeights,
        "inliers.verification": Verification,
        "inliers.rerank": Rerank,
    }
    if config.method not in METHOD_PRESETS:
        raise ConfigError(f"method = {config.method!r}; choose one of {', '.join(METHOD_PRESETS)} (with --method)")
    for dotted, literal in allowed.items():
        value = _get(config, dotted)
        if value not in literal.__args__:
            raise ConfigError(f"{dotted} = {value!r}; choose one of {', '.join(literal.__args__)}")
    for dotted, value in flat(config).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{dotted} = {value}; must be a finite number")
    for dotted, (low, high) in RANGES.items():
        if not low <= (value := _get(config, dotted)) <= high:
            raise ConfigError(f"{dotted} = {value}; must be within [{low}, {high}]")


def flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    """Every setting by its dotted key (`inliers.d_comp`)."""
    if not dataclasses.is_dataclass(tree):
        return {prefix.removesuffix("."): tree}
    return {key: value for f in dataclasses.fields(tree) for key, value in flat(getattr(tree, f.name), f"{prefix}{f.name}.").items()}


def _get(config: LocalizationConfig, dotted: str) -> Any:
    value: Any = config
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


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
