"""How far to trust a pose: P(translation error < the success threshold) per hypothesis.

A logistic regression over the features of `FEATURES` (standardized), then Platt scaling fitted on
leave-one-scene-out logits, so the probabilities are calibrated on scenes the regression did not
see. The coefficients of features that must not lower the confidence as they grow (the
verification score, its margin over the frame's other hypotheses) are bounded at >= 0, and the
Platt slope too: the confidence is monotone in them by construction. Features that differ between
scenes for reasons other than the pose's quality (missed landmarks: a cluttered desk's detector
misses many at the right pose) enter relative to the frame's other hypotheses.

The model is a JSON file (never a pickle): the shipped one is `clipclique/data/confidence.json`,
fitted by `tools/fit_confidence.py` (which also measures it on held-out scenes); `confidence_model`
in the config points to a refitted one. A feature is one line of `FEATURES`: a name, how to compute
it from a frame's `Evidence`, and the sign its coefficient is held to (0: free).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
from numba import njit
from scipy.special import expit, log_expit

from clipclique.errors import ClipcliqueError
from clipclique.numpybits import pairwise_sum
from clipclique.stack import Stack
from clipclique.verification import Verification

MODEL_FORMAT = "clipclique confidence model"
MODEL_VERSION = 1
L2 = 1e-2  # ridge on the standardized coefficients: a few hundred frames per scene, keep it smooth


@dataclass
class Evidence:
    """One frame's hypotheses and what was measured of them."""

    hypotheses: Stack  # (`Stack.of` a list of them)
    verification: Verification
    similarity: np.ndarray  # (K, N) the matrix the matching used
    num_observations: int


def _margin(score: np.ndarray) -> np.ndarray:
    """Each score minus the best other hypothesis's (the score itself when alone)."""
    if len(score) < 2:
        return score.copy()
    top = np.sort(score)[::-1]
    return score - np.where(score == top[0], top[1], top[0])


def _missed_in_frame(evidence: Evidence) -> np.ndarray:
    """Missed landmarks beyond the frame's least-missing hypothesis. How many landmarks a detector
    misses at the right pose depends on the scene (clutter, small objects: ~14 on the desk, under 1
    in a room), so the raw count and the score it lowers do not carry from one scene to another;
    what a hypothesis misses on top of the frame's best does."""
    missed = evidence.verification.missed.astype(float)
    return missed - missed.min()


def _summed_similarity(evidence: Evidence) -> np.ndarray:
    """Each hypothesis's similarity summed over its correspondences, to the bit as
    `similarity[tuple(correspondences.T)].sum()` adds them, one gather and one compiled pass for all (an index
    and a sum per hypothesis cost more than a frame's whole arithmetic)."""
    if not len(evidence.hypotheses):
        return np.zeros(0)
    pairs = evidence.hypotheses.pairs
    values = np.ascontiguousarray(evidence.similarity[pairs[:, 0], pairs[:, 1]])
    ends = np.cumsum(evidence.hypotheses.counts)
    return group_sums(values, ends).astype(float)


def group_sums(values: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """The sum of each group values[ends[b - 1]: ends[b]] of a contiguous array, in its type, to the bit as
    numpy's `.sum()` of each (a sum per group cost more than the arithmetic)."""
    return _group_sums(values, np.asarray(ends, np.int64), values.dtype.type(0))


@njit(cache=True)
def _group_sums(values: np.ndarray, ends: np.ndarray, zero) -> np.ndarray:
    """`group_sums` (`zero`: 0 of the values' type, where numpy's reduction starts: -0 sums to +0)."""
    sums = np.empty(len(ends), values.dtype)
    start = 0
    for b in range(len(ends)):
        sums[b] = zero + pairwise_sum(values, start, ends[b], zero)
        start = ends[b]
    return sums


FEATURES: dict[str, tuple[Callable[[Evidence], np.ndarray], int]] = {
    # The verification score with its missed penalty counted beyond the frame's fewest (by count, as the
    # model was fitted; with every missed landmark counted in full, verification.missed_full_area = 0, the
    # score plus a constant per frame, so monotone in it and with the same margins).
    "verification_in_frame": (lambda e: e.verification.overlap - e.verification.missed_weight * _missed_in_frame(e), +1),
    "margin": (lambda e: _margin(e.verification.score), +1),
    "mean_iou": (lambda e: e.verification.mean_iou, 0),
    "missed_in_frame": (_missed_in_frame, 0),
    "depth_error": (lambda e: np.minimum(e.verification.depth_error, 2.0), 0),
    "size": (lambda e: e.hypotheses.counts.astype(float), 0),
    "similarity": (lambda e: _summed_similarity(e), 0),
    "observations": (lambda e: np.full(len(e.hypotheses), float(e.num_observations)), 0),
}


def feature_matrix(evidence: Evidence, names: tuple[str, ...] = tuple(FEATURES)) -> np.ndarray:
    """(B, F) the named features of each hypothesis, written column by column into one array (a column stack and
    its float copy cost a frame a quarter of the features' own time)."""
    matrix = np.empty((len(evidence.verification.score), len(names)))
    for column, name in enumerate(names):
        matrix[:, column] = FEATURES[name][0](evidence)
    return matrix


@dataclass(frozen=True)
class ConfidenceModel:
    features: tuple[str, ...]
    mean: np.ndarray  # (F,) standardization
    scale: np.ndarray  # (F,)
    coefficients: np.ndarray  # (F,) on standardized features
    intercept: float
    platt: tuple[float, float]  # (slope, offset) applied to the logit
    provenance: dict  # what it was fitted on, and its held-out measurements

    def logit(self, features: np.ndarray) -> np.ndarray:
        return ((features - self.mean) / self.scale) @ self.coefficients + self.intercept

    def probability(self, features: np.ndarray) -> np.ndarray:
        """(B,) calibrated probability that each row's pose is within the success threshold."""
        slope, offset = self.platt
        return expit(slope * self.logit(features) + offset)

    def predict(self, evidence: Evidence) -> np.ndarray:
        return self.probability(feature_matrix(evidence, self.features))

    def to_json(self) -> dict:
        return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "features": list(self.features),
                "mean": self.mean.tolist(), "scale": self.scale.tolist(),
                "coefficients": self.coefficients.tolist(), "intercept": self.intercept,
                "platt": list(self.platt), "provenance": self.provenance}


def fit(features: np.ndarray, labels: np.ndarray, groups: np.ndarray, names: tuple[str, ...] = tuple(FEATURES),
        provenance: dict | None = None) -> ConfidenceModel:
    """Logistic regression on all rows; Platt scaling on leave-one-group-out logits (groups = scenes;
    with one group there is nothing held out and the Platt step is the identity)."""
    features, labels = np.asarray(features, float), np.asarray(labels, float)
    mean, scale = _standardization(features)
    signs = np.array([FEATURES[name][1] for name in names])
    weights, intercept = _logistic((features - mean) / scale, labels, signs)
    platt = (1.0, 0.0)
    scenes = np.unique(groups)
    if len(scenes) > 1:
        held_out = np.empty(len(labels))
        for scene in scenes:
            train = groups != scene
            m, s = _standardization(features[train])
            w, b = _logistic((features[train] - m) / s, labels[train], signs)
            held_out[~train] = ((features[~train] - m) / s) @ w + b
        platt = _platt(held_out, labels)
    return ConfidenceModel(tuple(names), mean, scale, weights, intercept, platt, provenance or {})


def _standardization(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column means and deviations (1 where a column is constant)."""
    scale = features.std(axis=0)
    return features.mean(axis=0), np.where(scale > 1e-9, scale, 1.0)


def _logistic(x: np.ndarray, y: np.ndarray, signs: np.ndarray) -> tuple[np.ndarray, float]:
    """L2-regularized logistic regression, coefficients held to `signs` (+1: >= 0, -1: <= 0, 0: free)."""
    from scipy.optimize import minimize  # fitting only: a localizing process need not import it

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        z = x @ theta[:-1] + theta[-1]
        value = -np.mean(y * log_expit(z) + (1 - y) * log_expit(-z)) + 0.5 * L2 * theta[:-1] @ theta[:-1]
        residual = (expit(z) - y) / len(y)
        return value, np.append(x.T @ residual + L2 * theta[:-1], residual.sum())

    bounds = [(0, None) if s > 0 else (None, 0) if s < 0 else (None, None) for s in signs] + [(None, None)]
    theta = minimize(loss, np.zeros(x.shape[1] + 1), jac=True, method="L-BFGS-B", bounds=bounds).x
    return theta[:-1], float(theta[-1])


def _platt(logits: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(slope >= 0, offset) minimizing the log loss of expit(slope * logit + offset)."""
    weights, offset = _logistic(logits[:, None], y, np.array([1]))
    return float(weights[0]), offset


def shipped_model_path() -> Path:
    return Path(str(resources.files("clipclique") / "data" / "confidence.json"))


@lru_cache(maxsize=4)
def load_model(path: str = "") -> ConfidenceModel | None:
    """The model in `path` ("" = the shipped one; None when the package ships none yet)."""
    file = Path(path) if path else shipped_model_path()
    if not path and not file.is_file():
        return None
    try:
        data = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:  # ValueError: not JSON, or not UTF-8
        raise ClipcliqueError(f"{file}: cannot read the confidence model ({error})") from None
    if not isinstance(data, dict) or data.get("format") != MODEL_FORMAT or data.get("version") != MODEL_VERSION:
        raise ClipcliqueError(f"{file}: not a version {MODEL_VERSION} {MODEL_FORMAT} file")
    try:
        names = tuple(data["features"])
        arrays = [np.asarray(data[key], float) for key in ("mean", "scale", "coefficients")]
        intercept, platt = float(data["intercept"]), tuple(float(v) for v in data["platt"])
    except (KeyError, TypeError, ValueError) as error:
        raise ClipcliqueError(f"{file}: malformed confidence model ({error!r})") from None
    unknown = [name for name in names if name not in FEATURES]
    if unknown:
        raise ClipcliqueError(f"{file}: unknown features {', '.join(unknown)} (known: {', '.join(FEATURES)})")
    if any(a.shape != (len(names),) for a in arrays) or not all(np.isfinite(a).all() for a in arrays) or len(platt) != 2:
        raise ClipcliqueError(f"{file}: mean, scale and coefficients must be {len(names)} finite numbers each, "
                              "platt two")
    return ConfidenceModel(names, *arrays, intercept, platt, data.get("provenance", {}))
