"""Fit the map-to-map alignment confidence (clipclique.multiframe.mapalign) on generated cases, measured on held-out
ones.

    .venv/bin/python tools/fit_align_confidence.py --seeds 200   # prints the constants and their calibration

Generated cases (seeded), each a query map, a map and the true transform:
- split: a random room of 40 landmarks cut into two parts overlapping by 1-2 m, 15% of each part's
  landmarks dropped, the query part moved by a random transform, 2 cm centre noise;
- submap: the 8 landmarks nearest one landmark, moved, against the whole room;
- unrelated: a part of one room against another room (no transform is right);
- copies: a part of a room against ten copies of it side by side (only the copy it came from is right);
- detectors (two per seed): one room mapped by two simulated detectors over parts overlapping by 0.3-1.2 m,
  each with its own misses, false positives and confusions, one with a coarser vocabulary, no comparable
  text embeddings (clipclique.sim.mappairs): the few-correspondence wrong answers real maps give.
Every reported candidate is labelled right when every query landmark lands within 0.3 m of where the truth
puts it and its rotation is within 5 degrees (mapalign.TOLERANCE_M, TOLERANCE_DEG). A logistic regression of the
evidence (mapalign.EVIDENCE: correspondences, margin, score, class rarity, spread, rms against the map's scale,
the rotation's standard error), on the candidates mapalign.supported does not cap, is fitted on even seeds and
measured on odd ones (a reliability table, and the top-1 answers: wrong ones
above 0.5 and not ambiguous, right ones refused), beside the model before (log correspondences and margin
only); then refitted on all: paste the printed constants into clipclique/multiframe/mapalign.py.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterator

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, log_expit

from clipclique.config import make_config
from clipclique.multiframe import mapalign
from clipclique.pipeline import align_maps
from clipclique.pose.distance import rotation_angle
from clipclique.sim.mappairs import detector_pair
from clipclique.sim.poses import random_rotation
from clipclique.sim.synthetic import duplicate_rooms, synthetic_map
from clipclique.types import Map, Pose

KINDS = ("split", "submap", "unrelated", "copies", "detectors")
# the model before the evidence (issue 38): log correspondences and margin only
WRONG_WEIGHT = 3.0  # 1 gives the same answers on the test's detector pairs (tools/align_pairs.py), 1 fewer refused
BEFORE = np.array([-7.009, 2.251, 15.571, 0.0, 0.0, 0.0, 0.0, 0.0])


def cases(seed: int) -> Iterator[tuple[str, Map, Map, Pose | None]]:
    """(kind, query map, map, true query-to-map transform or None) of one seed."""
    rng = np.random.default_rng(seed)
    room = synthetic_map(rng, 40)
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    x = room.ellipsoids.centers[:, 0]
    cut, band = rng.uniform(2.0, 3.0), rng.uniform(0.5, 1.0)
    keep = lambda index: index[rng.random(len(index)) > 0.15]  # noqa: E731
    query = moved(room.subset(keep(np.flatnonzero(x < cut + band))), truth, rng)
    yield "split", query, room.subset(keep(np.flatnonzero(x > cut - band))), truth
    near = np.argsort(np.linalg.norm(room.ellipsoids.centers - room.ellipsoids.centers[rng.integers(len(room))],
                                     axis=1))
    yield "submap", moved(room.subset(near[:8]), truth, rng), room, truth
    yield "unrelated", query, synthetic_map(rng, 40), None
    yield "copies", moved(room.subset(near[:12]), truth, rng), duplicate_rooms(room, 10), truth
    for _ in range(2):
        yield "detectors", *detector_pair(rng)


def moved(map: Map, truth: Pose, rng: np.random.Generator, noise: float = 0.02) -> Map:
    """`map` in the query frame (truth maps it back), centres jittered."""
    out = map.transformed(truth.inverse())
    out.ellipsoids.centers = out.ellipsoids.centers + rng.normal(scale=noise, size=out.ellipsoids.centers.shape)
    return out


def is_right(candidate: mapalign.Candidate, truth: Pose | None, query: Map) -> bool:
    """Every query landmark within TOLERANCE_M of where the truth puts it and the rotation within TOLERANCE_DEG
    (the query map's far landmarks show a turn its centroid hides)."""
    if truth is None:
        return False
    centers = query.ellipsoids.centers
    return (float(np.linalg.norm(candidate.pose.apply(centers) - truth.apply(centers), axis=1).max())
            < mapalign.TOLERANCE_M
            and math.degrees(rotation_angle(candidate.pose.rotation.T @ truth.rotation)) < mapalign.TOLERANCE_DEG)


def collect(seeds: range) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray, np.ndarray]:
    """(features (n, len(EVIDENCE)), labels (n,), kinds, whether each is a top-1 answer not called ambiguous,
    whether each is a competitor of an ambiguous alignment) of every reported candidate."""
    config = make_config("clipclique")
    features, labels, kinds, answers, contested = [], [], [], [], []
    for seed in seeds:
        for kind, query, map, truth in cases(seed):
            alignment = align_maps(query, map, config)
            scale = mapalign.map_scale(map)
            for rank, candidate in enumerate(alignment.candidates):
                features.append(mapalign.evidence(candidate, scale))
                labels.append(is_right(candidate, truth, query))
                kinds.append(kind)
                answers.append(rank == 0 and not alignment.ambiguous)
                contested.append(alignment.ambiguous and rank in alignment.competitors)
    return np.array(features), np.array(labels, float), kinds, np.array(answers), np.array(contested)


def fit(features: np.ndarray, labels: np.ndarray, contested: np.ndarray) -> np.ndarray:
    """(bias, weights...) of the logistic regression, a small ridge, on the candidates no cap of `mapalign.supported`
    holds (the capped ones are never confident, whatever the model says); wrong candidates weigh more than right
    ones (WRONG_WEIGHT: a wrong edge in a pose graph costs more than a refused right one)."""
    free = np.array([mapalign.supported(1.0, row, c) == 1.0 for row, c in zip(features, contested)])
    features, labels = features[free], labels[free]
    design = np.column_stack((np.ones(len(features)), features))
    weight = np.where(labels > 0, 1.0, WRONG_WEIGHT)

    def loss(weights: np.ndarray) -> float:
        logits = design @ weights
        return float(-np.sum(weight * (labels * log_expit(logits) + (1 - labels) * log_expit(-logits)))
                     + 1e-3 * weights[1:] @ weights[1:])

    return minimize(loss, np.zeros(design.shape[1]), method="BFGS").x


def answers_line(name: str, probability: np.ndarray, labels: np.ndarray, kinds: list[str], answers: np.ndarray) -> str:
    """The top-1 answers (not ambiguous) per kind: wrong ones at confidence >= 0.5, right ones refused (< 0.5)."""
    parts = []
    for kind in KINDS:
        rows = answers & (np.array(kinds) == kind)
        wrong, right = rows & (labels == 0), rows & (labels == 1)
        parts.append(f"{kind}: {int((probability[wrong] >= 0.5).sum())} of {int(wrong.sum())} wrong above 0.5, "
                     f"{int((probability[right] < 0.5).sum())} of {int(right.sum())} right refused")
    return f"{name}: " + "; ".join(parts)


def reliability(probability: np.ndarray, labels: np.ndarray) -> str:
    lines = ["confidence bin | candidates | right"]
    for low in np.arange(0.0, 1.0, 0.2):
        inside = (probability >= low) & (probability < low + 0.2 + (low >= 0.8))
        if inside.any():
            lines.append(f"{low:.1f}-{low + 0.2:.1f} | {int(inside.sum())} | {100 * labels[inside].mean():.0f}%")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=200, help="seeds per half (fit, held out)")
    args = parser.parse_args()
    train = collect(range(0, 2 * args.seeds, 2))
    held = collect(range(1, 2 * args.seeds, 2))
    weights = fit(train[0], train[1], train[4])
    design = np.column_stack((np.ones(len(held[0])), held[0]))
    probability, before = expit(design @ weights), expit(design @ BEFORE)
    probability = np.array([mapalign.supported(p, f, c) for p, f, c in zip(probability, held[0], held[4])])
    print(f"held-out seeds ({len(held[0])} candidates), model fitted on the others:")
    print(reliability(probability, held[1]))
    for kind in KINDS:
        rows = [i for i, k in enumerate(held[2]) if k == kind]
        print(f"{kind}: {len(rows)} candidates, {100 * held[1][rows].mean():.0f}% right, "
              f"mean confidence {probability[rows].mean():.2f} (before {before[rows].mean():.2f})")
    print(answers_line("before", before, held[1], held[2], held[3]))
    print(answers_line("after", probability, held[1], held[2], held[3]))
    final = fit(np.concatenate((train[0], held[0])), np.concatenate((train[1], held[1])),
                np.concatenate((train[4], held[4])))
    print(f"# fitted by tools/fit_align_confidence.py --seeds {args.seeds} (WRONG_WEIGHT {WRONG_WEIGHT}, "
          f"{4 * args.seeds} detector pairs among {len(train[0]) + len(held[0])} candidates)")
    print(f"BIAS, WEIGHTS = {final[0]:.3f}, ({', '.join(f'{w:.3f}' for w in final[1:])})")


if __name__ == "__main__":
    main()
