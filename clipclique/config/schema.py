"""The configuration's schema: every setting with the paper's default and its valid range beside it (`ranged`).

The sections are dataclasses, so a setting is a name, a type and a default in one place; presets
(clipclique.config.presets) and overrides (clipclique.config.overrides) only change their values.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

from clipclique.errors import ClipcliqueError
from clipclique.types import MAX_DEPTH_M

Descriptor = Literal["fused", "clip", "sh", "xview"]
MatchingStrategy = Literal["adaptive", "knn", "one_to_one"]
InlierMethod = Literal["cliques", "ransac", "prosac"]
PoseWeights = Literal["none", "sim", "com", "both"]
Verification = Literal["overlap", "centers"]
Rerank = Literal["none", "verification", "confidence"]


class ConfigError(ClipcliqueError):
    """A configuration file or override is wrong; the message says which key and why."""


def ranged(default: Any, low: float, high: float) -> Any:
    """A setting with its valid range [low, high] beside it (checked by `validate`)."""
    return field(default=default, metadata={"range": (low, high)})


@dataclass
class GraphConfig:
    d_adj: float = ranged(0.8, 1e-6, 100.0)  # metres: landmarks closer than this are neighbours
    # neighbours kept per node at most (memory bound; real scenes stay under ~30)
    max_degree: int = ranged(64, 1, 10_000)
    # Semantic Histogram path length s (nodes per walk). Walks grow as degree^(s-1) and codes as
    # C^s: s = 5 is beyond the paper's 3 and safe.
    walk_length: int = ranged(3, 1, 5)
    xview_walks: int = ranged(100, 1, 10_000)  # X-View: random walks per node
    xview_seed: int = ranged(0, 0, 2**63 - 1)


@dataclass
class SimilarityConfig:
    descriptor: Descriptor = "fused"
    alpha: float = ranged(0.7, 0.0, 1.0)  # S = alpha * S_clip + (1 - alpha) * S_sh
    # Beyond the paper (0 = the paper's literal SH): S_sh <- w * S_class + (1 - w) * S_sh, so an
    # object with no neighbour within d_adj (an empty histogram) still matches by its class.
    class_weight: float = ranged(0.3, 0.0, 1.0)
    # Beyond the paper (0 = exact labels): weight of a look-alike class (clipclique.descriptors.lookalikes) in the
    # class term and the query's Semantic Histograms, so a cup detected as "bottle" still finds cups.
    lookalike_weight: float = ranged(0.6, 0.0, 1.0)
    # Beyond the paper (off = hard map classes): where the map holds class distributions (an imported
    # SLAM map's class counts, clipclique.types.Map.class_distributions), the class term and the map's
    # Semantic Histograms use them as soft labels instead of the most likely class alone.
    soft_classes: bool = False


@dataclass
class MatchingConfig:
    strategy: MatchingStrategy = "adaptive"
    k: int = ranged(3, 1, 1000)  # kNN
    top_m_fraction: float = ranged(0.25, 1e-6, 1.0)  # adaptive: M = fraction of the landmarks
    min_similarity: float = ranged(0.0, -1.0, 1.0)  # candidates at or below this are dropped
    # Beyond the paper (0 = the gap rule alone): adaptive matching also keeps, per observation, this many of the
    # most similar landmarks of each look-alike class of its own (similarity.lookalike_weight > 0) whose size
    # agrees with the observation's (lookalike_size_ratio; matching.with_lookalikes), so a cup detected as
    # "bottle" keeps its cups as candidates; with re-ranking, each clique holding such a pair is also fitted
    # without it (README "Beyond the paper", clipclique/benchmark/accuracy_levers.py).
    lookalike_candidates: int = ranged(2, 0, 1000)
    # ... only landmarks whose sorted semi-axes are each within this factor of the observation's (1000: any size)
    lookalike_size_ratio: float = ranged(1.5, 1.0, 1000.0)
    # Candidates kept at most (the best-scored; matching.cap): more would only flood the
    # compatibility graph (and memory). Hitting it is reported (CapHit.MAX_CANDIDATES).
    max_candidates: int = ranged(20_000, 1, 10_000_000)


@dataclass
class InlierConfig:
    method: InlierMethod = "cliques"
    d_comp: float = ranged(0.3, 1e-6, 100.0)  # metres: rigid distance test of the compatibility graph
    # Beyond the paper (0 = the literal test): a candidate whose observed ellipsoid is smaller than
    # its landmark (a part of a couch, a bed, a counter) has its centre displaced by up to the
    # difference of their semi-axes; the pair test is widened by this fraction of each candidate's
    # largest semi-axis deficit (when it is at least slack_min_deficit), at most max_slack metres per candidate.
    partial_slack: float = ranged(1.5, 0.0, 100.0)
    max_slack: float = ranged(0.8, 0.0, 100.0)  # metres
    slack_min_deficit: float = ranged(0.2, 0.0, 100.0)  # metres (tools/sweep_slack.py: README "Beyond the paper")
    # Landmark pairs the compatibility test may hold in memory (about 100 MB); the best-scored
    # candidates that fit are kept and the cap reported (CapHit.MAX_PAIRS).
    max_pairs: int = ranged(2_000_000, 1, 1_000_000_000)
    # Beyond the paper: from this many candidates (or beyond matching.max_candidates), candidates that lie in
    # several map regions farther apart than compatibility reaches (a building of look-alike rooms) are searched
    # region by region, copies of one room once (clipclique.inliers.regions), when copies at least halve the searches:
    # the same hypotheses; num_cliques then counts each region's own search, and the candidate cap applies per
    # region. Rooms that differ are searched as one map, capped as before.
    region_split_from: int = ranged(2_000, 1, 1_000_000_000)
    min_clique_size: int = ranged(3, 3, 1000)  # fewer than 3 cannot fix a 6-DoF pose
    max_cliques: int = ranged(100_000, 1, 10_000_000)  # enumeration stops here and says so
    time_limit_s: float = ranged(1.0, 1e-6, 3600.0)  # enumeration stops here and says so
    ransac_iterations: int = ranged(1000, 1, 10_000_000)
    # metres: RANSAC/PROSAC centre residual to count as inlier (centers)
    inlier_threshold: float = ranged(0.5, 1e-6, 100.0)
    seed: int = ranged(0, 0, 2**63 - 1)
    verification: Verification = "overlap"  # RANSAC/PROSAC: projected box overlap (the paper) or 3D centre distance
    iou_threshold: float = ranged(0.3, 0.0, 1.0)  # RANSAC/PROSAC overlap verification: box IoU to count as inlier
    # Beyond the paper ("none" = the clique score's order): reorder every method's hypotheses by image
    # verification or confidence. Verification wins on every generated scene (tools/accuracy_levers.py).
    rerank: Rerank = "verification"
    # Beyond the paper: with re-ranking, the inlier stage fits this many hypotheses (the heaviest cliques),
    # verification keeps the top_n best. On a cluttered desk the right clique is often not among the
    # heaviest five: look-alike objects form heavier wrong ones (clipclique/benchmark/accuracy_levers.py).
    rerank_pool: int = ranged(50, 1, 1000)
    # Beyond the paper (0 = off): observations whose boxes overlap at least this much (IoU) are one
    # object seen twice (a detector's cross-class duplicate): never both in one clique.
    duplicate_iou: float = ranged(0.7, 0.0, 1.0)


@dataclass
class PoseConfig:
    weights: PoseWeights = "both"  # w = s_total * w_com ("sim" = s_total only, "com" = w_com only)
    # A correspondence set whose centres are nearly a row (pose.conditioning below this) gives no
    # pose: with 0.1 m centre noise most such poses are over 1 m off (tools/bench_conditioning.py).
    min_conditioning: float = ranged(0.05, 0.0, 1.0)
    # Beyond the paper (0 = off): metres; each pose refitted with every observation it moves this
    # close to a landmark it is similar to (clipclique.pose.refine)
    refine_radius: float = ranged(0.3, 0.0, 10.0)
    # Beyond the paper (0 = off): Levenberg-Marquardt steps aligning each kept hypothesis's landmarks, projected
    # as conics, with its observations' detection boxes (clipclique.verify.boxalign): a few partly seen objects fix
    # a pose loosely by their centres, their boxes sharply. A pose is kept only where its robust cost fell. At 3,
    # top-1 within 0.05 m gains 8-29 points on five generated scenes of six, but demo loses 2-3 frames of 120 at
    # 0.25-0.5 m (large objects whose ellipsoids miss their boxes): off (docs/methods.md, benchmark/accuracy_levers.py).
    box_refine_steps: int = ranged(0, 0, 50)
    box_refine_scale: float = ranged(5.0, 1e-3, 1e4)  # pixels: a box side this far off costs Cauchy's knee
    # metres (0 = boxes alone): each pair's observed centre off its landmark's by this costs as much, a prior that
    # keeps the boxes from pulling the pose where the centres it was fitted to disagree
    box_refine_centre_m: float = ranged(0.05, 0.0, 100.0)
    # the weight of a box's size beside its offset (1: the four sides alike): a map ellipsoid's outline is smaller
    # than its object's box, so the size pulls the camera nearer
    box_refine_size_weight: float = ranged(1.0, 0.0, 10.0)
    # a fraction (0 = pixels alone): a box's residuals in units of sqrt(scale^2 + (this * its diagonal)^2) pixels:
    # a large object's ellipsoid misses its box by more pixels than a small one's
    box_refine_relative: float = ranged(0.1, 0.0, 10.0)


@dataclass
class VerificationConfig:
    """Image verification of every hypothesis (clipclique.verify.verification)."""

    # metres: depth disagreement at which an overlap counts for nothing
    depth_tolerance: float = ranged(0.5, 1e-6, 100.0)
    missed_weight: float = ranged(0.25, 0.0, 100.0)  # a missed landmark costs a quarter of a perfect overlap
    min_visible_pixels: int = ranged(1500, 0, 100_000_000)  # projected boxes smaller than this may well go undetected
    # a detection of the landmark's class overlapping this much explains it
    explained_iou: float = ranged(0.1, 0.0, 1.0)
    # Beyond the first verification (0 = each missed landmark costs missed_weight): a missed landmark costs in
    # full when its projected box covers this fraction of the image (a sixteenth: 160 x 120 of 640 x 480), in
    # proportion when smaller. Detectors miss small objects most (a cluttered desk's right pose misses a score
    # of them); a large object that nobody detected still rules a pose out (clipclique.verify.verification).
    missed_full_area: float = ranged(0.0625, 0.0, 1.0)
    # Beyond the paper (0 = off: each missed landmark costs alike however many the pose expects): where a pose
    # expects more than this much evidence (its landmarks in view counted by size, as missed ones are), its
    # missed evidence is scaled by this / expected: it pays for the share it missed. A cluttered desk's right
    # pose misses a dozen small objects, a wrong one looking past the desk a few
    # (clipclique/benchmark/accuracy_levers.py).
    missed_share_from: float = ranged(3.0, 0.0, 1000.0)


@dataclass(frozen=True)
class FitParams:
    """How a point set becomes an ellipsoid (clipclique.perception.ellipsoids)."""

    outlier_neighbors: int = ranged(20, 1, 1000)  # statistical outlier removal: neighbours considered
    outlier_std_ratio: float = ranged(2.0, 1e-6, 1e12)  # ... points farther than mean + ratio * std are cut
    min_points: int = ranged(30, 4, 10_000_000)  # fewer points than this: no ellipsoid
    min_axis: float = ranged(0.01, 0.0, 100.0)  # metres: a semi-axis shorter than this is degenerate (flat/line)
    max_points: int = ranged(20_000, 4, 100_000_000)  # larger sets are subsampled (evenly, deterministic) first


@dataclass(frozen=True)
class ObservationParams:
    """How a detection becomes an observed ellipsoid (clipclique.perception.observations)."""

    min_mask_pixels: int = ranged(100, 1, 100_000_000)  # smaller masks are too noisy to fit
    erode_px: int = ranged(2, 0, 100)  # mask erosion before back-projection (kept only if enough pixels survive)
    # metres: farther depth is unreliable on consumer RGB-D sensors; also the range image
    # verification projects the map to (types.Camera.max_depth)
    max_depth: float = ranged(MAX_DEPTH_M, 1e-3, 1000.0)
    border_px: int = ranged(8, 0, 10_000)  # a mask is truncated when it comes this close to the image border
    max_border_fraction: float = ranged(0.5, 0.0, 1.0)  # ... and dropped when more of it lies in that band (a sliver)
    fit: FitParams = field(default_factory=lambda: FitParams(max_points=5000))  # one view is dense: 5000 suffice


@dataclass
class LocalizationConfig:
    method: str = "clipclique"
    graph: GraphConfig = field(default_factory=GraphConfig)
    similarity: SimilarityConfig = field(default_factory=SimilarityConfig)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    inliers: InlierConfig = field(default_factory=InlierConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    observations: ObservationParams = field(default_factory=ObservationParams)
    top_n: int = ranged(5, 1, 1000)
    success_threshold_m: float = ranged(1.0, 1e-6, 1e5)
    # hypotheses less confident are dropped; a frame left without one is not localized
    min_confidence: float = ranged(0.0, 0.0, 1.0)
    confidence_model: str = ""  # JSON file of a refitted confidence model ("": the one shipped in the package)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
