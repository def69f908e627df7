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
in the config points to a refitted one. A feature is one entry of `FEATURES` (a name and the sign its
coefficient is held to, 0: free) and one column of the compiled `_features`, which computes it from a frame's
`Evidence`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
from numba import njit
from scipy.special import expit, log_expit

from clipclique.errors import ClipcliqueError
from clipclique.pose.stack import Stack
from clipclique.verify.verification import Verification

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


# Each feature: its name, its column number in `_features` (the order here) and the sign its coefficient is held
# to (0: free). How each is computed from a frame's `Evidence` (`_features` computes the same values in one pass):
# - verification_in_frame: overlap - missed_weight * missed_in_frame: the verification score with its missed
#   penalty counted beyond the frame's fewest (by count, as the model was fitted; with every missed landmark
#   counted in full, verification.missed_full_area = 0, the score plus a constant per frame, so monotone in it
#   and with the same margins);
# - margin: each score minus the best other hypothesis's (the score itself when alone);
# - mean_iou: the verification's;
# - missed_in_frame: missed landmarks beyond the frame's least-missing hypothesis. How many landmarks a detector
#   misses at the right pose depends on the scene (clutter, small objects: ~14 on the desk, under 1 in a room),
#   so the raw count and the score it lowers do not carry from one scene to another; what a hypothesis misses on
#   top of the frame's best does;
# - depth_error: the verification's, at most 2 m;
# - size: how many correspondences;
# - similarity: the similarity summed over the correspondences, in the matrix's type, as numpy's `.sum()`;
# - observations: the frame's observations.
FEATURES: dict[str, int] = {"verification_in_frame": +1, "margin": +1, "mean_iou": 0, "missed_in_frame": 0,
                            "depth_error": 0, "size": 0, "similarity": 0, "observations": 0}
_COLUMN = {name: column for column, name in enumerate(FEATURES)}


def feature_matrix(evidence: Evidence, names: tuple[str, ...] = tuple(FEATURES)) -> np.ndarray:
    """(B, F) the named features of each hypothesis (`FEATURES`), in one compiled pass (`_features`): a numpy call
    or two per feature cost a frame more than all their arithmetic."""
    measured = _measured(evidence)
    return _features(_columns(tuple(names)), np.arange(len(measured[1])), *measured)


def _measured(evidence: Evidence) -> tuple:
    """What `_features` reads of the evidence, after the columns and rows."""
    checked, hypotheses = evidence.verification, evidence.hypotheses
    return (checked.overlap, checked.score, checked.mean_iou, checked.missed, checked.depth_error,
            float(checked.missed_weight), hypotheses.counts, hypotheses.pairs, evidence.similarity,
            float(evidence.num_observations))


@lru_cache(maxsize=16)
def _columns(names: tuple[str, ...]) -> np.ndarray:
    """The columns of `_features` of the named features, in order (read-only: shared by every frame of a model)."""
    columns = np.array([_COLUMN[name] for name in names], np.int64)
    columns.flags.writeable = False
    return columns


@njit(cache=True)
def _features(columns, rows, overlap, score, mean_iou, missed, depth_error, missed_weight, counts, pairs, similarity,
              observations):
    """`feature_matrix` of the features numbered `columns` (their order in `FEATURES`) of the hypotheses `rows`, the
    frame's figures (its fewest missed, its best two scores) of all of them; each written as numpy's passes computed
    it: the missed count as a float less the frame's fewest, np.minimum's NaN, the margin against the scores np.sort
    orders (`_top_two`), the similarity gathered and summed per hypothesis from +0 in its type, as numpy's `.sum()`
    (within its rounding)."""
    matrix = np.empty((len(rows), len(columns)))
    starts = np.cumsum(counts) - counts
    total = np.zeros(1, similarity.dtype)  # the similarity's sum, rounded to its type at each step
    for j in range(len(columns)):
        column = columns[j]
        if column == 0 or column == 3:
            fewest = float(missed.min()) if len(missed) else 0.0
            for r in range(len(rows)):
                beyond = float(missed[rows[r]]) - fewest
                matrix[r, j] = overlap[rows[r]] - missed_weight * beyond if column == 0 else beyond
        elif column == 1:
            first, second = _top_two(score) if len(score) > 1 else (np.nan, np.nan)
            for r in range(len(rows)):
                value = score[rows[r]]
                matrix[r, j] = value if len(score) < 2 else value - (second if value == first else first)
        elif column == 2:
            for r in range(len(rows)):
                matrix[r, j] = mean_iou[rows[r]]
        elif column == 4:
            for r in range(len(rows)):
                error = depth_error[rows[r]]
                matrix[r, j] = error if error < 2.0 or np.isnan(error) else 2.0
        elif column == 5:
            for r in range(len(rows)):
                matrix[r, j] = counts[rows[r]]
        elif column == 6:
            for r in range(len(rows)):
                total[0] = 0.0
                for m in range(starts[rows[r]], starts[rows[r]] + counts[rows[r]]):
                    total[0] += similarity[pairs[m, 0], pairs[m, 1]]
                matrix[r, j] = total[0]
        else:
            matrix[:, j] = observations
    return matrix


@njit(cache=True)
def probabilities(rows, overlap, score, mean_iou, missed, depth_error, missed_weight, counts, pairs, similarity,
                  observations, columns, mean, scale, coefficients, intercept, slope, offset):
    """`ConfidenceModel.probability` of `_features` of the hypotheses `rows`, for compiled callers too
    (clipclique.verify.ranking): each row standardized, its products with the coefficients summed in column order
    (the matrix product's rounding may differ in the last bit), and 1 / (1 + exp(-x)) of the Platt-scaled logit."""
    features = _features(columns, rows, overlap, score, mean_iou, missed, depth_error, missed_weight, counts, pairs,
                         similarity, observations)
    probability = np.empty(len(features))
    for b in range(len(features)):
        logit = 0.0
        for j in range(features.shape[1]):
            logit += (features[b, j] - mean[j]) / scale[j] * coefficients[j]
        probability[b] = 1.0 / (1.0 + np.exp(-(slope * (logit + intercept) + offset)))
    return probability


@njit(cache=True)
def _top_two(values: np.ndarray) -> tuple[float, float]:
    """The first two of `np.sort(values)[::-1]` (two values or more) in one pass: the largest two, NaN first (np.sort
    puts NaN last). Where +0 and -0 tie for a place np.sort's order of them is its own: verification scores are never
    -0 (overlap sums from +0, less a cost of +0 or more)."""
    first = second = -np.inf
    nans = 0
    for value in values:
        if np.isnan(value):
            nans += 1
        elif value > first:
            first, second = value, first
        elif value > second:
            second = value
    if nans:
        return np.nan, (np.nan if nans > 1 else first)
    return first, second


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
        """`probability` of the evidence's `feature_matrix`, both in one compiled pass (`probabilities`): a frame's
        numpy standardization, product and expit cost more than their arithmetic."""
        measured = _measured(evidence)
        return probabilities(np.arange(len(measured[1])), *measured, *self.terms())

    def terms(self) -> tuple:
        """What `probabilities` reads of the model after the evidence: the features' columns, mean, scale,
        coefficients, intercept and the Platt slope and offset."""
        slope, offset = self.platt
        return (_columns(self.features), self.mean, self.scale, self.coefficients, float(self.intercept), float(slope),
                float(offset))

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
    signs = np.array([FEATURES[name] for name in names])
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
    if (any(a.shape != (len(names),) for a in arrays) or not all(np.isfinite(a).all() for a in arrays)
        or len(platt) != 2):
        raise ClipcliqueError(f"{file}: mean, scale and coefficients must be {len(names)} finite numbers each, "
                              "platt two")
    return ConfidenceModel(names, *arrays, intercept, platt, data.get("provenance", {}))
