"""The methods as presets of the one pipeline (the paper's Table I), and their names in the tables.

A preset is a set of dotted-key overrides over the schema's defaults (clipclique.config.schema), so a
method is nothing but a configuration.
"""

from __future__ import annotations

import difflib
import re
from typing import Any

from clipclique.config.schema import ConfigError

# The paper's Table I: each method is the one pipeline with parts swapped.
# The baselines keep the paper's literal descriptors (no class term, exact labels).
LITERAL = {"similarity.class_weight": 0.0, "similarity.lookalike_weight": 0.0, "inliers.partial_slack": 0.0,
           "inliers.rerank": "none", "inliers.duplicate_iou": 0.0, "pose.refine_radius": 0.0,
           "verification.missed_share_from": 0.0, "matching.lookalike_candidates": 0, "pose.box_refine_steps": 0}

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

METHOD_TITLES = {"clipclique": "CLIP-Clique", "clipclique-paper": "CLIP-Clique (paper)", "sh": "SH", "xview": "X-View",
                 "cliploc": "CLIP-Loc"}


def method_key(name: str) -> str:
    """The method `name` denotes: its key (`clipclique-paper`) or the title the tables print (`CLIP-Clique
    (paper)`), in any case and punctuation; a ConfigError naming the nearest method otherwise."""
    folded = {re.sub(r"[^a-z0-9]", "", spelling.lower()): key
              for key, title in METHOD_TITLES.items() for spelling in (key, title)}
    typed = re.sub(r"[^a-z0-9]", "", name.lower())
    if typed in folded:
        return folded[typed]
    near = difflib.get_close_matches(typed, folded, n=1, cutoff=0.6)
    hint = f"did you mean {folded[near[0]]}? " if near else ""
    raise ConfigError(f"--method {name}: no such method; {hint}choose {', '.join(METHOD_TITLES)} "
                      f"(or the names the tables print: {', '.join(METHOD_TITLES.values())})")
