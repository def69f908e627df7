"""How well a pose hypothesis explains the image: the map projected under it, against the detections.

Per hypothesis (all of a frame's at once), with the map's landmarks projected by
`clipclique.verify.projection`:
- overlap: the summed IoU between each corresponding observation's detection box and its
  landmark's projected box, each weighted by depth agreement, max(0, 1 - |dz| / depth_tolerance),
  where dz is the observed centre's depth along its ray minus the landmark centre's depth;
- missed: landmarks projected well inside the image (at least min_visible_pixels, half of their
  box on the image) that no detection of their class overlaps (IoU >= explained_iou): what the
  pose says should be seen but was not;
- missed evidence: each missed landmark counted by its size, fully when its projected box covers
  `missed_full_area` of the image, in proportion below: a detector misses small objects far more
  often than large ones, so on a cluttered desk the right pose misses a score of small things
  while a wrong one looking past the desk misses few (0 = every missed landmark counts fully);
- expected evidence: every landmark the pose expects to be seen (missed or not), counted by size alike;
- missed cost: missed_weight * missed evidence, scaled by `missed_share_from` / expected evidence where the
  pose expects more than `missed_share_from`: a pose looking into a crowd of objects is charged for the
  share of them nobody detected, not for their number (a real desk's detector misses 70% of the objects
  in view, so the right pose misses the most; 0 = every pose charged by number);
- score = overlap - missed cost: the verification score (`Hypothesis.verification`).

The constants are settings (`config.VerificationConfig`, `verification.*` keys).

RANSAC / PROSAC verify minimal-set poses by overlap alone (`candidate_overlap`), as CLIP-Loc does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from clipclique.config import VerificationConfig
from clipclique.errors import ClipcliqueError
from clipclique.pose.stack import Stack, alike_spans
from clipclique.types import Camera, Ellipsoids, Hypothesis, Map, Observations
from clipclique.verify import projection
from clipclique.verify.projection import at_least_zero, box_iou, corners_iou, project


@dataclass(kw_only=True)
class Verification:
    """Verification of B hypotheses, one entry each."""

    score: np.ndarray  # (B,) overlap - missed_cost(missed_evidence, expected_evidence)
    overlap: np.ndarray  # (B,) depth-weighted summed IoU over the correspondences
    mean_iou: np.ndarray  # (B,) plain IoU averaged over the correspondences
    missed: np.ndarray  # (B,) int, landmarks that should be visible but no detection explains
    missed_evidence: np.ndarray  # (B,) float, those landmarks counted by their projected size (missed_full_area)
    expected_evidence: np.ndarray  # (B,) float, every landmark expected in view (missed or not) counted alike
    depth_error: np.ndarray  # (B,) metres, median |dz| over the correspondences
    missed_weight: float  # what one missed landmark cost in `score`


def require_image(observations: Observations, why: str) -> None:
    """ClipcliqueError unless the observations carry their boxes and camera."""
    if observations.boxes is None or observations.camera is None:
        raise ClipcliqueError(f"{why} needs each observation's detection box and the camera "
                              "(Observations.boxes and .camera, filled by extract_observations)")


def verify(hypotheses: list[Hypothesis], observations: Observations, map: Map,
           params: VerificationConfig = VerificationConfig()) -> Verification:
    """Verification of each hypothesis against the observations' boxes and centres (`verify_stack`)."""
    return verify_stack(Stack.of(hypotheses), observations, map, params)


def verify_stack(stack: Stack, observations: Observations, map: Map,
                 params: VerificationConfig = VerificationConfig(), spreads: np.ndarray | None = None) -> Verification:
    """Verification of each hypothesis of the stack. Hypotheses alike (one pose, one set of pairs: refinement
    often brings several cliques of a re-ranked pool to one) are verified once; a hypothesis's figures do not
    depend on the others'. `spreads`: the map's `projection.spreads`, where kept (`pipeline.index_map`; None:
    computed here). One compiled call (`figures`): a frame's numpy calls and compiled calls between its steps cost
    more than their arithmetic."""
    require_image(observations, "image verification")
    return Verification(**dict(zip(_PER_HYPOTHESIS, figures(*figure_inputs(stack, observations, map, params,
                                                                          spreads)))),
                        missed_weight=params.missed_weight)


def figure_inputs(stack: Stack, observations: Observations, map: Map, params: VerificationConfig,
                  spreads: np.ndarray | None) -> tuple:
    """What `figures` reads, in its order: the stack's arrays, the map's and the observations' (boxes and camera
    given), the settings as numbers."""
    camera = observations.camera
    return (stack.rotations, stack.translations, stack.pairs, stack.counts,
            np.asarray(map.ellipsoids.centers, np.float64), map.ellipsoids.axes,
            projection.spreads(map.ellipsoids) if spreads is None else spreads,
            np.asarray(observations.boxes, np.float64), observations.ellipsoids.centers, map.class_ids,
            observations.class_ids, camera.intrinsics, float(camera.width), float(camera.height),
            float(camera.max_depth), float(params.depth_tolerance), float(params.min_visible_pixels),
            float(params.explained_iou), float(params.missed_full_area * camera.width * camera.height),
            float(params.missed_weight), float(params.missed_share_from))


@njit(cache=True)
def figures(rotations, translations, pairs, counts, centers, axes, spreads, boxes, observed_centers, class_ids,
            detected_classes, intrinsics, width, height, max_depth, depth_tolerance, min_pixels, explained_iou, full,
            missed_weight, share_from):
    """`verify_stack`'s figures (in `_PER_HYPOTHESIS`'s order), for compiled callers too (clipclique.verify.ranking):
    the distinct hypotheses and the landmarks in range (`_distinct_in_range`), those landmarks projected under the
    distinct poses (`projection.visible_boxes`), their figures (`_verdicts`)."""
    group, firsts, nearby, kept_rotations, kept_translations = _distinct_in_range(rotations, translations, pairs,
                                                                                  counts, centers, axes, max_depth)
    spread = np.empty((len(nearby), spreads.shape[1]))
    for column in range(len(nearby)):
        for k in range(spreads.shape[1]):
            spread[column, k] = spreads[nearby[column], k]
    projected, visible, full_areas = projection.visible_boxes(centers[nearby], spread, kept_rotations,
                                                              kept_translations, intrinsics, width, height, max_depth)
    return _verdicts(group, firsts, pairs, counts, kept_rotations, kept_translations, centers, nearby, len(centers),
                     visible, projected, full_areas, boxes, observed_centers, class_ids, detected_classes,
                     depth_tolerance, min_pixels, explained_iou, full, missed_weight, share_from)


_PER_HYPOTHESIS = ("score", "overlap", "mean_iou", "missed", "missed_evidence", "expected_evidence", "depth_error")


@njit(cache=True)
def _distinct_in_range(rotations, translations, pairs, counts, centers, axes, max_depth):
    """The stack's hypotheses alike (`stack.alike` of each pose's twelve numbers and its pairs): (B,) each one's group
    and (G,) each group's first; the landmarks some first's camera may see (`_in_range`, indices ascending); and the
    firsts' rotations and translations."""
    poses = np.empty((len(counts), 12))
    for b in range(len(counts)):
        for i in range(3):
            poses[b, 9 + i] = translations[b, i]
            for j in range(3):
                poses[b, 3 * i + j] = rotations[b, i, j]
    values = np.ascontiguousarray(pairs).reshape(-1)
    group, firsts = alike_spans(poses.view(np.int64), values, 2 * (np.cumsum(counts) - counts), 2 * counts)
    kept_rotations, kept_translations = rotations[firsts], translations[firsts]
    return group, firsts, np.flatnonzero(_in_range(centers, axes, kept_translations, max_depth)), kept_rotations, \
        kept_translations


@njit(cache=True)
def _verdicts(group, firsts, pairs, counts, rotations, translations, centers, nearby, map_size, visible, projected,
              full_areas, boxes, observed_centers, class_ids, detected_classes, depth_tolerance, min_pixels,
              explained_iou, full, missed_weight, share_from):
    """`verify_stack`'s figures (in `_PER_HYPOTHESIS`'s order) of the hypotheses `firsts` (their poses `rotations`,
    `translations`; the landmarks `nearby` projected under them), then given to each hypothesis of its `group`: the
    pairs of the firsts (`_rows_pairs`), their landmarks' depths (`_depths_along`), `_measures`, the score less the
    missed cost (`_missed_costs`)."""
    obs, lm, owner, sizes = _rows_pairs(pairs, counts, firsts)
    landmark_depths = _depths_along(centers, lm, translations, rotations, owner)
    overlap, mean_iou, depth_error, missed, evidence, expected = _measures(
        obs, lm, owner, nearby, map_size, visible, projected, full_areas, boxes, observed_centers[:, 2],
        landmark_depths, class_ids, detected_classes, sizes, depth_tolerance, min_pixels, explained_iou, full)
    score = overlap - _missed_costs(evidence, expected, missed_weight, share_from)
    return (score[group], overlap[group], mean_iou[group], missed[group], evidence[group], expected[group],
            depth_error[group])


@njit(cache=True)
def _rows_pairs(pairs: np.ndarray, counts: np.ndarray,
                rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pairs of the hypotheses `rows` (of pairs (M, 2), `counts` each, hypothesis after hypothesis) in one pass:
    their observations, landmarks and owners (the position in `rows`) and their counts, as `Stack.take(rows)`'s
    pairs[:, 0], pairs[:, 1], owners() and counts, without its six gathers."""
    starts = np.empty(len(counts), np.int64)
    total = 0
    for b in range(len(counts)):
        starts[b] = total
        total += counts[b]
    taken = counts[rows]
    size = taken.sum()
    obs, lm, owner = np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size, np.int64)
    at = 0
    for r in range(len(rows)):
        for m in range(starts[rows[r]], starts[rows[r]] + taken[r]):
            obs[at], lm[at], owner[at] = pairs[m, 0], pairs[m, 1], r
            at += 1
    return obs, lm, owner, taken


@njit(cache=True)
def _depths_along(centers: np.ndarray, lm: np.ndarray, translations: np.ndarray, rotations: np.ndarray,
                  owner: np.ndarray) -> np.ndarray:
    """(M,) each pair's landmark depth along its pose's optical axis, `np.einsum("mi,mi->m", centers[lm] -
    translations[owner], rotations[owner, :, 2])`, without the two gathers and einsum's setup."""
    depths = np.empty(len(lm))
    for m in range(len(lm)):
        center, translation, axis = centers[lm[m]], translations[owner[m]], rotations[owner[m], :, 2]
        x0, x1, x2 = center[0] - translation[0], center[1] - translation[1], center[2] - translation[2]
        depths[m] = x0 * axis[0] + x1 * axis[1] + x2 * axis[2]
    return depths


@njit(cache=True)
def _measures(obs, lm, owner, nearby, map_size, visible, projected, full_areas, boxes, observed_depths, landmark_depths,
             class_ids, detected_classes, sizes, depth_tolerance, min_pixels, explained_iou, full):
    """`_pair_measures` and `_missed_evidence` of the landmarks in range (`nearby`, projected in that order) in one
    compiled call, with what they read: each landmark's column of the projection (-1 out of range) and each pair's
    depth gap |observed depth - landmark depth| (numpy's subtraction and absolute value): (B,) overlap, mean IoU,
    median depth gap, missed landmarks, missed and expected evidence."""
    slot = np.full(map_size, -1, np.int64)
    seen_classes = np.empty(len(nearby), np.int64)
    for column in range(len(nearby)):
        slot[nearby[column]] = column
        seen_classes[column] = class_ids[nearby[column]]
    depth_gap = np.empty(len(obs))
    for m in range(len(obs)):
        depth_gap[m] = abs(observed_depths[obs[m]] - landmark_depths[m])
    overlap, mean_iou, depth_error = _pair_measures(obs, lm, owner, slot, visible, projected, boxes, depth_gap,
                                                   depth_tolerance, sizes)
    missed, evidence, expected = _missed_evidence(projected, visible, full_areas, seen_classes, boxes, detected_classes,
                                                  min_pixels, explained_iou, full)
    return overlap, mean_iou, depth_error, missed, evidence, expected


def missed_cost(missed_evidence: np.ndarray, expected_evidence: np.ndarray, params: VerificationConfig) -> np.ndarray:
    """(B,) what the missed landmarks cost in the score: missed_weight per unit of missed evidence, times
    missed_share_from / expected evidence where the pose expects more than missed_share_from (0: never).
    A pose expecting few landmarks pays for each one missed; one expecting a crowd pays for the share missed,
    as if it expected missed_share_from: on a cluttered desk the right pose misses a dozen small objects
    and a wrong one looking past the desk a few, yet the share each misses tells them apart."""
    return _missed_costs(np.asarray(missed_evidence, np.float64), np.asarray(expected_evidence, np.float64),
                         float(params.missed_weight), float(params.missed_share_from))


@njit(cache=True)
def _missed_costs(missed_evidence: np.ndarray, expected_evidence: np.ndarray, weight: float,
                  share_from: float) -> np.ndarray:
    """`missed_cost` as numpy computed it, weight * missed evidence, times share_from / np.maximum(expected evidence,
    share_from) (NaN kept) unless share_from is 0."""
    cost = np.empty(len(missed_evidence))
    for b in range(len(cost)):
        cost[b] = weight * missed_evidence[b]
        if share_from != 0:
            expected = expected_evidence[b]
            cost[b] = cost[b] * (share_from / (expected if expected > share_from or np.isnan(expected) else share_from))
    return cost


@njit(cache=True)
def _pair_measures(obs, lm, owner, slot, visible, projected, boxes, depth_gap, depth_tolerance, sizes):
    """(B,) overlap, mean IoU and median depth gap of each hypothesis's pairs (obs, lm, owner ascending, slot:
    each landmark's column of the projection, -1 out of range), in one pass as numpy's passes computed them:
    the IoU 0 out of view, agreement max(0, 1 - gap / tolerance), sums in pair order from 0 (np.bincount's)."""
    overlap, iou_sums = np.zeros(len(sizes)), np.zeros(len(sizes))
    for m in range(len(obs)):
        b, at = owner[m], slot[lm[m]]
        o = obs[m]
        iou = corners_iou(boxes[o, 0], boxes[o, 1], boxes[o, 2], boxes[o, 3], projected[b, at, 0], projected[b, at, 1],
                          projected[b, at, 2], projected[b, at, 3]) if at >= 0 and visible[b, at] else 0.0
        overlap[b] += iou * at_least_zero(1.0 - depth_gap[m] / depth_tolerance)
        iou_sums[b] += iou
    return overlap, iou_sums / np.maximum(sizes, 1), _group_medians(depth_gap, sizes)


@njit(cache=True)
def _group_medians(values, sizes):
    """np.median of each group of values (group b: the next sizes[b]; inf for an empty group), the same values
    where no NaN is in it, each group sorted stably (NaN last) by an insertion sort into one scratch array (a group is a
    hypothesis's dozen pairs; an argsort allocates twice a group): a median is (lower + upper) / 2 of the middle
    pair, as numpy computes it (the middle value twice when the count is odd)."""
    medians = np.empty(len(sizes))
    ordered = np.empty(len(values))
    start = 0
    for b in range(len(sizes)):
        for i in range(sizes[b]):
            value = values[start + i]
            j = i
            while j > 0 and (ordered[j - 1] > value or (np.isnan(ordered[j - 1]) and not np.isnan(value))):
                ordered[j] = ordered[j - 1]
                j -= 1
            ordered[j] = value
        medians[b] = (ordered[(sizes[b] - 1) // 2] + ordered[sizes[b] // 2]) / 2 if sizes[b] else np.inf
        start += sizes[b]
    return medians


@njit(cache=True)
def _in_range(centers: np.ndarray, axes: np.ndarray, translations: np.ndarray, max_depth: float) -> np.ndarray:
    """(N,) whether a landmark some camera (B positions) may see: `np.linalg.norm(centers - translation) -
    axes.max(axis=1) <= max_depth` for some translation (never where an axis is NaN), without a (B, N, 3) array of
    differences. Of a large map only these are projected."""
    near = np.zeros(len(centers), np.bool_)
    for n in range(len(centers)):
        a0, a1, a2 = axes[n, 0], axes[n, 1], axes[n, 2]  # by index: a row's view is counted in and out
        size = np.nan if np.isnan(a0) or np.isnan(a1) or np.isnan(a2) else max(a0, a1, a2)
        for b in range(len(translations)):
            dx = centers[n, 0] - translations[b, 0]
            dy = centers[n, 1] - translations[b, 1]
            dz = centers[n, 2] - translations[b, 2]
            if np.sqrt(dx * dx + dy * dy + dz * dz) - size <= max_depth:
                near[n] = True
                break
    return near


def candidate_overlap(rotations: np.ndarray, translations: np.ndarray, landmarks: Ellipsoids, boxes: np.ndarray,
                      camera: Camera) -> np.ndarray:
    """(B, C) IoU of each candidate's observation box (C, 4) with its landmark (C ellipsoids) projected
    under each camera-to-map pose (B); 0 where the landmark is not visible."""
    seen = project(landmarks, rotations, translations, camera)
    return np.where(seen.visible, box_iou(boxes[None], seen.boxes), 0.0)


@njit(cache=True)
def _missed_evidence(boxes: np.ndarray, visible: np.ndarray, full_areas: np.ndarray, class_ids: np.ndarray,
                     detected: np.ndarray, detected_classes: np.ndarray, min_pixels: float, explained_iou: float,
                     full: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`_missed` of the projected boxes (B, N, 4) in one pass, pose after pose, landmark after landmark, as numpy's
    passes computed it: the area box_area's, a landmark expected where visible with area >= min_pixels and half
    its unclipped area, weighed min(1, area / full) (1 where full is 0), summed in that order from 0."""
    count, size = visible.shape
    missed, evidence, expected = np.zeros(count, np.int64), np.zeros(count), np.zeros(count)
    for b in range(count):
        for n in range(size):  # numbers only, no array view or array argument: each costs two atomic refcounts
            x0, y0, x1, y1 = boxes[b, n, 0], boxes[b, n, 1], boxes[b, n, 2], boxes[b, n, 3]
            area = at_least_zero(x1 - x0) * at_least_zero(y1 - y0)
            if visible[b, n] and area >= min_pixels and area >= 0.5 * full_areas[b, n]:
                weight = (1.0 if area / full >= 1.0 else area / full) if full > 0 else 1.0
                expected[b] += weight
                explained = False  # a detection of its class overlaps it with IoU >= explained_iou
                for k in range(len(detected)):
                    if detected_classes[k] == class_ids[n] and corners_iou(
                            x0, y0, x1, y1, detected[k, 0], detected[k, 1], detected[k, 2],
                            detected[k, 3]) >= explained_iou:
                        explained = True
                        break
                if not explained:
                    missed[b] += 1
                    evidence[b] += weight
    return missed, evidence, expected
