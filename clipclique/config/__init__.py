"""Parameters with the paper's defaults; methods and ablations are configurations of one pipeline.

The package's front door (`from clipclique.config import make_config`): `schema` holds the settings and their
ranges, `presets` the methods, `overrides` how a preset, a file and `key=value` overrides make one configuration.
"""

from clipclique.config.overrides import (
    MAX_CONFIG_BYTES,
    apply_overrides,
    changed_by_overrides,
    flat,
    load_file,
    make_config,
    parse_assignments,
    validate,
)
from clipclique.config.presets import LITERAL, METHOD_PRESETS, METHOD_TITLES, method_key
from clipclique.config.schema import (
    ConfigError,
    Descriptor,
    FitParams,
    GraphConfig,
    InlierConfig,
    InlierMethod,
    LocalizationConfig,
    MatchingConfig,
    MatchingStrategy,
    ObservationParams,
    PoseConfig,
    PoseWeights,
    Rerank,
    SimilarityConfig,
    Verification,
    VerificationConfig,
    ranged,
)

__all__ = [
    "LITERAL", "MAX_CONFIG_BYTES", "METHOD_PRESETS", "METHOD_TITLES", "ConfigError", "Descriptor", "FitParams",
    "GraphConfig", "InlierConfig", "InlierMethod", "LocalizationConfig", "MatchingConfig", "MatchingStrategy",
    "ObservationParams", "PoseConfig", "PoseWeights", "Rerank", "SimilarityConfig", "Verification",
    "VerificationConfig", "apply_overrides", "changed_by_overrides", "flat", "load_file", "make_config", "method_key",
    "parse_assignments", "ranged", "validate",
]
