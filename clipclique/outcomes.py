"""How a query went, as types: the stages it passes, the bounds it may hit, why it may give no pose.

A frame's failure is a `Failure` (a `FailureKind` and the numbers its message needs); the text
written to results.json is derived from it (`Failure.message`), so code matches on the kind and
never parses the text. Stage names are defined here once, for the pipeline's timings and the
runner's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum, StrEnum

import numpy as np

from clipclique.types import Hypothesis


class Stage(StrEnum):
    """A timed stage of one query; the value is the key of `timings` and of results.json."""

    DETECTOR = "detector"
    OBSERVATIONS = "observations"
    ENCODER = "encoder"
    DESCRIPTORS = "descriptors"
    SIMILARITY = "similarity"
    MATCHING = "matching"
    INLIERS = "inliers"
    POSE = "pose"
    VERIFICATION = "verification"


QUERY_STAGES = (Stage.DETECTOR, Stage.OBSERVATIONS, Stage.ENCODER)  # the runner's, before the pipeline's
PIPELINE_STAGES = (Stage.DESCRIPTORS, Stage.SIMILARITY, Stage.MATCHING, Stage.INLIERS, Stage.POSE, Stage.VERIFICATION)
ALL_STAGES = QUERY_STAGES + PIPELINE_STAGES
ALGORITHM_STAGES = (Stage.MATCHING, Stage.INLIERS, Stage.POSE)  # the paper's time per query


class CapHit(StrEnum):
    """A bound that stopped work early; the value is what results.json says."""

    MAX_CANDIDATES = "max_candidates"  # matching.max_candidates: the best-scored candidates kept
    MAX_PAIRS = "max_pairs"  # inliers.max_pairs: candidates dropped so their landmark pairs fit in memory
    MAX_CLIQUES = "max_cliques"  # inliers.max_cliques: the clique search stopped counting
    TIME_LIMIT = "time_limit"  # inliers.time_limit_s: the clique search ran out of time


@dataclass(frozen=True, kw_only=True)
class RegionSplit:
    """How a frame of many candidates in several map regions was searched: region by region
    (clipclique.inliers.regions, `inliers.region_split_from`).

    A building of identical rooms is truly ambiguous: every copy of the room holding the heaviest
    clique holds one as heavy, and `tied_regions` says in how many places the frame fits equally well.
    """

    regions: int  # map regions holding candidates, each searched alone
    layouts: int  # distinct regions among them (the others are copies of one, searched once)
    tied_regions: int  # the region holding the heaviest clique and its copies; 0 without a clique

    @property
    def ambiguous(self) -> bool:
        """Whether more than one region holds the heaviest clique."""
        return self.tied_regions > 1


class FailureKind(Enum):
    """Which stage left a frame without a pose."""

    FEW_OBSERVATIONS = "few_observations"  # fewer than 3 observations
    FEW_MATCHED = "few_matched"  # fewer than 3 observations with a candidate landmark
    NO_CLIQUE = "no_clique"  # the compatibility graph has no clique of min_clique_size
    NO_MINIMAL_SET = "no_minimal_set"  # RANSAC / PROSAC found no consistent minimal set
    DEGENERATE = "degenerate"  # every correspondence set was collinear or poorly conditioned
    NOT_CONFIDENT = "not_confident"  # every pose fell below min_confidence
    NO_POSE = "no_pose"  # a solver without stages of its own found none (tools/literal_reference.py)


@dataclass(frozen=True, kw_only=True)
class Failure:
    """Why a frame has no pose: the kind and the numbers its message quotes."""

    kind: FailureKind
    count: int = 0  # FEW_OBSERVATIONS, FEW_MATCHED: observations; NO_CLIQUE: the minimum clique size
    min_confidence: float = 0.0  # NOT_CONFIDENT: the floor
    best_confidence: float = 0.0  # NOT_CONFIDENT: the most confident pose's confidence

    @property
    def message(self) -> str:
        """The sentence results.json and the viewer show."""
        if self.kind is FailureKind.FEW_OBSERVATIONS:
            return f"fewer than 3 observations ({self.count})"
        if self.kind is FailureKind.FEW_MATCHED:
            return f"fewer than 3 observations with a candidate landmark ({self.count})"
        if self.kind is FailureKind.NO_CLIQUE:
            return f"no clique of {self.count} or more compatible correspondences"
        if self.kind is FailureKind.NO_MINIMAL_SET:
            return "no minimal set of 3 distinct, non-collinear correspondences"
        if self.kind is FailureKind.DEGENERATE:
            return "no correspondence set determines a pose (each is collinear or poorly conditioned)"
        if self.kind is FailureKind.NOT_CONFIDENT:
            return f"no pose with confidence >= {self.min_confidence:g} (best {self.best_confidence:.2f})"
        return "no pose"

    @property
    def reason(self) -> str:
        """The message without the frame's observation count: what a benchmark tallies frames by."""
        if self.kind in (FailureKind.FEW_OBSERVATIONS, FailureKind.FEW_MATCHED):
            return self.message.removesuffix(f" ({self.count})")
        return self.message

    def __str__(self) -> str:
        return self.message


@dataclass(kw_only=True)
class LocalizationResult:
    """What `pipeline.localize` found for one frame."""

    hypotheses: list[Hypothesis]  # best first, at most config.top_n
    candidates: np.ndarray  # (C, 2) int (observation index, landmark index) after initial matching
    candidate_scores: np.ndarray  # (C,) similarity of each candidate
    similarity: np.ndarray  # (K, N) the matrix the matching used
    num_cliques: int  # maximal cliques the search reached (the rest cut by its bound), or RANSAC/PROSAC hypotheses
    cap_hit: CapHit | None  # the first bound hit, None when none was
    failure: Failure | None  # why there is no pose; None on success
    region_split: RegionSplit | None = None  # the regions searched one by one (inliers.region_split_from)
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)  # seconds per stage (outcomes.PIPELINE_STAGES)
    # (C,) candidates only `matching.lookalike_candidates` added (the gap rule did not keep them); None: none were
    lookalike_added: np.ndarray | None = None
