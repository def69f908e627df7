"""Map-to-map alignment: the rigid transform taking one object map (the query map) into another.

The entry point is `clipclique.pipeline.align_maps(query_map, map, config)`; this module prepares the
query (`as_query`) and turns the pipeline's hypotheses into candidates (`conclude`).

Multi-session mapping and object-based loop closing need the transform between two object maps of
one place. The query map is given to the localization pipeline as if it were one huge frame:
its landmarks become observations (centres, axes, classes; the text embeddings stand in for image
embeddings when both maps share an encoder, else alpha = 0, Semantic Histograms only), and
descriptors, matching, cliques and the weighted pose run unchanged. Each hypothesis is a 4 x 4
matrix taking query-map coordinates into the map.

Vocabularies: a query class is the map class of the same name (any case) or of a synonym
(`lookalikes.SYNONYM_PAIRS`: couch/sofa, tv/monitor, ...); a class the map lacks is added to the
vocabulary, where the look-alike kernel still relates it to the map's classes.

Hypotheses whose transforms agree (the query map's centroid within DISTINCT_M and rotations within
DISTINCT_DEG) are one candidate: cliques that differ by a correspondence or two. Each candidate
is refined: every query landmark that lands within `inliers.d_comp` of a map landmark of a like
class (nearest first, one-to-one) becomes a correspondence, and the transform is refit on them.

Maps cannot be verified in an image, so a candidate's confidence comes from its evidence (EVIDENCE):
the number of correspondences, its margin (how far its summed similarity stands above the best other
candidate's, relative to its own), the similarity per correspondence, the matched classes' rarity in the
map, the matched landmarks' spread, the residual against the map's scale (`map_scale`), and how well the
correspondences pin the rotation (`rotation_sigma`). A logistic model of them, fitted on generated cases
(`tools/fit_align_confidence.py`: split maps moved by random transforms, unrelated maps, rooms repeated
side by side, and maps of one room by two simulated detectors, `clipclique.sim.mappairs`), gives the
probability that the transform is right (every query landmark within TOLERANCE_M of where the truth puts
it, the rotation within TOLERANCE_DEG). Three kinds of candidate are never confident (`supported`): fewer
than MIN_SUPPORT correspondences (a coincidence of a few objects), the competitors of an ambiguous answer, and a
rotation whose standard error about its least constrained axis is more than 1 / PRECISION_SIGMAS of
TOLERANCE_DEG; the model is fitted on the candidates no cap holds. The last is what wrong answers
of 6-9 correspondences between two detectors' maps mostly are: the right objects matched over a thin
overlap (a band of the room, so the points barely constrain a turn about one axis), the rotation 5-12
degrees off; their rms, margin and count look like those of right answers, the rotation's standard error
does not. (Tried and not kept, measured on 1,400 generated pairs: an a-contrario tail of k like-class
coincidences under a random placement, unmatched query landmarks landing on map landmarks of another
class, and the rotation's change when one correspondence is left out; none separated the wrong answers
that the rotation's standard error leaves.)
The answer is `ambiguous` when another candidate scores within AMBIGUOUS_MARGIN of the
best: the competitors are listed instead of one being picked silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from clipclique.config import LocalizationConfig
from clipclique.descriptors import lookalikes
from clipclique.outcomes import Failure, LocalizationResult
from clipclique.pose.distance import rotation_angle
from clipclique.pose.fit import DegeneratePoseError, fit_rigid
from clipclique.types import Map, Observations, Pose

DISTINCT_M = 0.5  # metres: transforms moving the query centroid less apart than this ...
DISTINCT_DEG = 10.0  # ... and rotating less apart than this are one candidate
AMBIGUOUS_MARGIN = 0.15  # a competitor within this fraction of the best's similarity makes the answer ambiguous
SEARCHED = 4  # hypotheses asked of the pipeline per candidate reported (near-duplicates are merged)
# Logistic confidence, P = sigmoid(BIAS + WEIGHTS . evidence), the evidence being EVIDENCE (`evidence`), fitted on
# the candidates `supported` leaves uncapped (its output says how well it is calibrated). The features are
# correlated (the rotation's standard error grows with the rms and shrinks with the count and the spread): read
# the weights together, not one by one.
EVIDENCE = ("log correspondences", "margin", "score per correspondence", "class rarity", "log spread (m)",
            "rms / map scale", "log rotation sigma (deg)")
TOLERANCE_M, TOLERANCE_DEG = 0.3, 5.0  # a transform is right when its landmarks and rotation are this close
MIN_SUPPORT, SPARSE_CAP = 6, 0.4  # fewer correspondences than this: never confident (`supported`)
PRECISION_SIGMAS = 2.0  # ... nor a rotation whose standard error times this exceeds TOLERANCE_DEG
# fitted by tools/fit_align_confidence.py --seeds 200 (WRONG_WEIGHT 3.0, 800 detector pairs among 10250 candidates)
BIAS, WEIGHTS = -5.474, (1.844, 7.029, 3.810, 0.663, 6.000, 3.590, -5.292)
TRANSLATION_FLOOR_M = 0.01  # the information matrix's translation sigma is at least this
INFORMATION_CAP = 1e6  # ... and no entry exceeds this


@dataclass
class Candidate:
    """One transform of the query map into the map."""

    pose: Pose  # query-map coordinates -> map coordinates
    correspondences: np.ndarray  # (M, 2) int rows (query-map landmark, map landmark)
    score: float  # summed similarity of the correspondences
    margin: float  # (score - the best other candidate's score) / score; 1 without another
    confidence: float  # P(the transform is right), module docstring
    rms_m: float  # root-mean-square centre residual of the correspondences after the transform
    spread_m: float = 0.0  # radius of gyration of the matched query landmarks (a rotation needs spread points)
    rarity: float = 0.0  # mean -log(share of the map's landmarks of the matched class): rare classes say more
    rotation_sigma_deg: float = 0.0  # the rotation's standard error about its least constrained axis (`rotation_sigma`)

    def matrix(self) -> np.ndarray:
        return self.pose.matrix()


@dataclass
class MapAlignment:
    candidates: list[Candidate]  # best first, at most config.top_n
    ambiguous: bool  # another candidate scores within AMBIGUOUS_MARGIN of the best
    competitors: list[int]  # indices into candidates scoring within AMBIGUOUS_MARGIN of the best (the best included)
    vocabulary: dict[str, str | None]  # query class name -> the map class it was matched to (None: added)
    failure: Failure | None  # why the pipeline found no transform; None when it found one
    notes: list[str] = field(default_factory=list)


@dataclass
class AlignmentQuery:
    """The query map as the pipeline's query, and the map in the shared vocabulary (`as_query`)."""

    observations: Observations  # the query map's landmarks, classes in the shared vocabulary
    map: Map  # the map with the shared vocabulary
    config: LocalizationConfig  # the config the pipeline runs with (`_alignment_config`)
    vocabulary: dict[str, str | None]  # query class name -> the map class it matched (None: added)
    notes: list[str]


def as_query(query_map: Map, map: Map, config: LocalizationConfig) -> AlignmentQuery:
    """What `clipclique.pipeline.align_maps` localizes: the query map's landmarks as observations."""
    names, query_ids, vocabulary = shared_vocabulary(query_map.class_names, map.class_names)
    notes: list[str] = []
    settings = _alignment_config(config, query_map, map, notes)
    observations = Observations(query_map.ellipsoids, query_ids[query_map.class_ids],
                                None if settings.similarity.alpha == 0 else query_map.text_embeddings,
                                query_map.instance_ids, np.arange(len(query_map)))
    return AlignmentQuery(observations, replace(map, class_names=names), settings, vocabulary, notes)


def conclude(result: LocalizationResult, query: AlignmentQuery, query_map: Map,
             config: LocalizationConfig) -> MapAlignment:
    """The pipeline's hypotheses as distinct, refined, ranked candidates with confidences (module docstring)."""
    kernel = lookalikes.class_kernel(query.map.class_names, 1.0)
    like = kernel[query.observations.class_ids][:, query.map.class_ids].toarray() > 0  # (query, map) classes alike
    candidates: list[Candidate] = []
    for hypothesis in result.hypotheses:
        if any(_same_transform(hypothesis.pose, c.pose, query_map) for c in candidates):
            continue
        refined = _refinement(hypothesis.pose, hypothesis.correspondences, query.observations, query.map, like,
                           result.similarity, query.config.inliers.d_comp)
        if not any(_same_transform(refined.pose, c.pose, query_map) for c in candidates):  # converged onto another
            candidates.append(refined)
    candidates.sort(key=lambda c: -c.score)
    best = candidates[0].score if candidates else 0.0
    competitors = ([i for i, c in enumerate(candidates) if c.score >= (1 - AMBIGUOUS_MARGIN) * best] if candidates
                   else [])
    _confidences(candidates, map_scale(query.map), competitors if len(competitors) > 1 else [])
    return MapAlignment(candidates[:config.top_n], len(competitors) > 1, [i for i in competitors if i < config.top_n],
                        query.vocabulary, result.failure, query.notes + result.notes)


def shared_vocabulary(query_names: list[str],
                      map_names: list[str]) -> tuple[list[str], np.ndarray, dict[str, str | None]]:
    """The map's vocabulary extended by the query classes it lacks; (names, query class id -> id in
    names, query class name -> the map class it matched or None)."""
    names = list(map_names)
    ids, matched = [], {}
    for name in query_names:
        found = lookalikes.synonym(name, list(map_names))
        matched[name] = None if found is None else map_names[found]
        if found is None:
            found = next((i for i, entry in enumerate(names) if entry.lower() == name.lower()), None)
            if found is None:
                names.append(name)
                found = len(names) - 1
        ids.append(found)
    return names, np.array(ids, np.int64), matched


def _alignment_config(config: LocalizationConfig, query_map: Map, map: Map, notes: list[str]) -> LocalizationConfig:
    """The config with what maps lack turned off: no image (no re-ranking or confidence floor, and RANSAC's
    verification by 3D centres, not projected boxes: every method aligns), CLIP only between maps of one
    encoder; and more hypotheses, since near-duplicates are merged."""
    inliers = replace(config.inliers, rerank="none", verification="centers")
    settings = replace(config, top_n=SEARCHED * config.top_n, inliers=inliers,
                       min_confidence=0.0, similarity=replace(config.similarity))
    same_encoder = (query_map.text_embeddings is not None and map.text_embeddings is not None
                    and query_map.encoder == map.encoder)
    if settings.similarity.descriptor == "clip" or (settings.similarity.descriptor == "fused" and not same_encoder):
        if settings.similarity.alpha > 0:
            notes.append(f"text embeddings not comparable (query map: {query_map.encoder}, map: {map.encoder}): "
                         "alpha = 0 (Semantic Histograms only)")
        settings.similarity = replace(settings.similarity, descriptor="fused", alpha=0.0)
    return settings


def _same_transform(a: Pose, b: Pose, query_map: Map) -> bool:
    centroid = query_map.ellipsoids.centers.mean(axis=0)
    return (float(np.linalg.norm(a.apply(centroid) - b.apply(centroid))) < DISTINCT_M
            and math.degrees(rotation_angle(a.rotation.T @ b.rotation)) < DISTINCT_DEG)


def _refinement(pose: Pose, clique: np.ndarray, observations: Observations, map: Map, like: np.ndarray,
             similarity: np.ndarray, reach: float) -> Candidate:
    """Every query landmark within `reach` of a like map landmark under `pose` (nearest first, one-to-one),
    and the transform refit on them; the clique as it is when fewer than three are found."""
    moved = pose.apply(observations.ellipsoids.centers)
    tree = cKDTree(map.ellipsoids.centers)
    pairs = [(float(np.linalg.norm(moved[q] - map.ellipsoids.centers[m])), q, m)
             for q, near in enumerate(tree.query_ball_point(moved, reach)) for m in near if like[q, m]]
    used_q, used_m, chosen = set(), set(), []
    for _, q, m in sorted(pairs):
        if q not in used_q and m not in used_m:
            chosen.append((q, m))
            used_q.add(q)
            used_m.add(m)
    correspondences = np.array(sorted(chosen), np.int64).reshape(-1, 2)
    try:
        pose = fit_rigid(observations.ellipsoids.centers[correspondences[:, 0]],
                         map.ellipsoids.centers[correspondences[:, 1]])
    except DegeneratePoseError:
        correspondences = clique
    residual = (pose.apply(observations.ellipsoids.centers[correspondences[:, 0]])
                - map.ellipsoids.centers[correspondences[:, 1]])
    score = float(np.clip(similarity[correspondences[:, 0], correspondences[:, 1]], 0.0, None).sum())
    points = observations.ellipsoids.centers[correspondences[:, 0]]
    spread = float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))
    share = np.bincount(map.class_ids, minlength=len(map.class_names)) / max(len(map), 1)
    rarity = float(np.mean(-np.log(share[map.class_ids[correspondences[:, 1]]])))
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    return Candidate(pose, correspondences, score, 1.0, 0.0, rms, spread, rarity, rotation_sigma(points, rms))


def rotation_sigma(points: np.ndarray, rms_m: float) -> float:
    """Degrees: the standard error of a rotation fitted on `points` with residual `rms_m`, about the axis they
    constrain least. A turn by a small angle about an axis moves each point by its distance from the axis times
    the angle, so in least squares the angle's variance is the per-coordinate noise (rms / sqrt 3) squared over
    the smallest principal moment of the points about their centroid (the sum of squared distances from that
    axis). Points along a line (or in a thin band of a room) leave one turn loose, whatever their spread."""
    centred = points - points.mean(axis=0)
    moments = np.sum(centred**2) * np.eye(3) - centred.T @ centred
    smallest = max(float(np.linalg.eigvalsh(moments)[0]), TRANSLATION_FLOOR_M**2)
    return math.degrees(max(rms_m, TRANSLATION_FLOOR_M) / math.sqrt(3 * smallest))


def map_scale(map: Map) -> float:
    """The median distance from a map landmark to its nearest neighbour: how far apart wrong matches can lie,
    the unit a candidate's residual is measured in."""
    if len(map) < 2:
        return 1.0
    distances, _ = cKDTree(map.ellipsoids.centers).query(map.ellipsoids.centers, k=2)
    return max(float(np.median(distances[:, 1])), TRANSLATION_FLOOR_M)


def _confidences(candidates: list[Candidate], scale: float, contested: list[int]) -> None:
    """Margin and confidence of each candidate (best first); `contested`: the competitors of an ambiguous answer."""
    for i, candidate in enumerate(candidates):
        other = max((c.score for j, c in enumerate(candidates) if j != i), default=0.0)
        candidate.margin = (candidate.score - other) / candidate.score if candidate.score > 0 else 0.0
        candidate.confidence = confidence(evidence(candidate, scale), i in contested)


def evidence(candidate: Candidate, scale: float) -> np.ndarray:
    """The features the confidence weighs (EVIDENCE, in order)."""
    size = max(len(candidate.correspondences), 1)
    return np.array([math.log(size), candidate.margin, candidate.score / size, candidate.rarity,
                     math.log(max(candidate.spread_m, TRANSLATION_FLOOR_M)), candidate.rms_m / scale,
                     math.log(candidate.rotation_sigma_deg)])


def confidence(features: np.ndarray, contested: bool = False) -> float:
    """P(right) of a candidate of these `evidence` features (module docstring), capped by `supported`."""
    return supported(float(1.0 / (1.0 + math.exp(-(BIAS + float(np.dot(WEIGHTS, features)))))), features, contested)


def supported(probability: float, features: np.ndarray, contested: bool = False) -> float:
    """`probability`, at most SPARSE_CAP when the `evidence` cannot establish the transform: fewer than MIN_SUPPORT
    correspondences (on maps of one place made by two detectors mostly a coincidence of a few objects, generated
    pairs: 17 of 19 wrong, which the margin and residual of the few cannot tell apart from the truth), a rotation
    whose standard error is more than TOLERANCE_DEG / PRECISION_SIGMAS (the objects may be the right ones, the
    turn is not known to within the tolerance), or a `contested` candidate (one of an ambiguous answer's
    competitors: the evidence does not single it out)."""
    sparse = round(math.exp(features[0])) < MIN_SUPPORT
    loose = PRECISION_SIGMAS * math.exp(features[EVIDENCE.index("log rotation sigma (deg)")]) > TOLERANCE_DEG
    return min(probability, SPARSE_CAP) if sparse or loose or contested else probability


def g2o_edge(candidate: Candidate, query_map: Map) -> str:
    """The candidate as a g2o `EDGE_SE3:QUAT 0 1 tx ty tz qx qy qz qw` line with its information matrix.

    Vertex 0 is the map, vertex 1 the query map: the measurement is the query map's frame in the map's,
    i.e. the candidate's transform. The information matrix (upper triangle, row by row, of the 6 x 6 in
    g2o's order x y z qx qy qz) is diagonal: translation 1 / sigma_t^2 with sigma_t = max(rms residual,
    TRANSLATION_FLOOR_M) / sqrt(correspondences); rotation 1 / sigma_q^2 with sigma_q = sigma_t / (2 r),
    r the correspondences' radius of gyration about their centroid in the query map (a rotation by a
    small angle moves points at r by r * angle; the quaternion's vector part is half the angle).
    Entries are capped at INFORMATION_CAP.
    """
    pose = candidate.pose
    count = max(len(candidate.correspondences), 1)
    sigma_t = max(candidate.rms_m, TRANSLATION_FLOOR_M) / math.sqrt(count)
    points = query_map.ellipsoids.centers[candidate.correspondences[:, 0]]
    radius = float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1)))) if len(points) else 0.0
    sigma_q = sigma_t / (2 * max(radius, TRANSLATION_FLOOR_M))
    diagonal = [min(1 / sigma_t**2, INFORMATION_CAP)] * 3 + [min(1 / sigma_q**2, INFORMATION_CAP)] * 3
    information = np.diag(diagonal)
    upper = information[np.triu_indices(6)]
    quaternion = Rotation.from_matrix(pose.rotation).as_quat()  # x y z w
    values = [*pose.translation, *quaternion]
    return "EDGE_SE3:QUAT 0 1 " + " ".join(f"{v:.9g}" for v in values) + " " + " ".join(f"{v:.6g}" for v in upper)
