"""Fit the map-to-map alignment confidence (clipclique.multiframe.mapalign) on generated cases, measured on held-out ones.

    .venv/bin/python tools/fit_align_confidence.py            # prints the constants and their calibration

Generated cases (seeded), each a query map, a map and the true transform:
- split: a random room of 40 landmarks cut into two parts overlapping by 1-2 m, 15% of each part's
  landmarks dropped, the query part moved by a random transform, 2 cm centre noise;
- submap: the 8 landmarks nearest one landmark, moved, against the whole room;
- unrelated: a part of one room against another room (no transform is right);
- copies: a part of a room against ten copies of it side by side (only the copy it came from is right).
Every reported candidate is labelled right when it moves the query map's centroid within 0.5 m of
where the truth puts it and its rotation is within 5 degrees. A logistic regression of
(log correspondences, margin) is fitted on even seeds and measured on odd ones (a reliability table),
then refitted on all; paste the printed constants into clipclique/multiframe/mapalign.py.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterator

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, log_expit

from clipclique.multiframe import mapalign
from clipclique.config import make_config
from clipclique.pipeline import align_maps
from clipclique.geometry import random_rotation, rotation_angle
from clipclique.sim.synthetic import duplicate_rooms, synthetic_map
from clipclique.types import Map, Pose

KINDS = ("split", "submap", "unrelated", "copies")


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
    near = np.argsort(np.linalg.norm(room.ellipsoids.centers - room.ellipsoids.centers[rng.integers(len(room))], axis=1))
    yield "submap", moved(room.subset(near[:8]), truth, rng), room, truth
    yield "unrelated", query, synthetic_map(rng, 40), None
    yield "copies", moved(room.subset(near[:12]), truth, rng), duplicate_rooms(room, 10), truth


def moved(map: Map, truth: Pose, rng: np.random.Generator, noise: float = 0.02) -> Map:
    """`map` in the query frame (truth maps it back), centres jittered."""
    out = map.transformed(truth.inverse())
    out.ellipsoids.centers = out.ellipsoids.centers + rng.normal(scale=noise, size=out.ellipsoids.centers.shape)
    return out


def is_right(candidate: mapalign.Candidate, truth: Pose | None, query: Map) -> bool:
    if truth is None:
        return False
    centroid = query.ellipsoids.centers.mean(axis=0)
    return (float(np.linalg.norm(candidate.pose.apply(centroid) - truth.apply(centroid))) < 0.5
            and math.degrees(rotation_angle(candidate.pose.rotation.T @ truth.rotation)) < 5.0)


def collect(seeds: range) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(features (n, 2), labels (n,), kinds) of every reported candidate."""
    config = make_config("clipclique")
    features, labels, kinds = [], [], []
    for seed in seeds:
        for kind, query, map, truth in cases(seed):
            for candidate in align_maps(query, map, config).candidates:
                features.append((math.log(max(len(candidate.correspondences), 1)), candidate.margin))
                labels.append(is_right(candidate, truth, query))
                kinds.append(kind)
    return np.array(features), np.array(labels, float), kinds


def fit(features: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(bias, size weight, margin weight) of the logistic regression, a small ridge."""
    design = np.column_stack((np.ones(len(features)), features))

    def loss(weights: np.ndarray) -> float:
        logits = design @ weights
        return float(-np.sum(labels * log_expit(logits) + (1 - labels) * log_expit(-logits)) + 1e-3 * weights[1:] @ weights[1:])

    return minimize(loss, np.zeros(3), method="BFGS").x


def reliability(probability: np.ndarray, labels: np.ndarray) -> str:
    lines = ["confidence bin | candidates | right"]
    for low in np.arange(0.0, 1.0, 0.2):
        inside = (probability >= low) & (probability < low + 0.2 + (low >= 0.8))
        if inside.any():
            lines.append(f"{low:.1f}-{low + 0.2:.1f} | {int(inside.sum())} | {100 * labels[inside].mean():.0f}%")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=60, help="seeds per half (fit, held out)")
    args = parser.parse_args()
    train = collect(range(0, 2 * args.seeds, 2))
    held = collect(range(1, 2 * args.seeds, 2))
    weights = fit(train[0], train[1])
    probability = expit(np.column_stack((np.ones(len(held[0])), held[0])) @ weights)
    print("held-out seeds, model fitted on the others:")
    print(reliability(probability, held[1]))
    for kind in KINDS:
        rows = [i for i, k in enumerate(held[2]) if k == kind]
        print(f"{kind}: {len(rows)} candidates, {100 * held[1][rows].mean():.0f}% right, "
              f"mean confidence {probability[rows].mean():.2f}")
    final = fit(np.concatenate((train[0], held[0])), np.concatenate((train[1], held[1])))
    print(f"BIAS, SIZE_WEIGHT, MARGIN_WEIGHT = {final[0]:.3f}, {final[1]:.3f}, {final[2]:.3f}")


if __name__ == "__main__":
    main()
