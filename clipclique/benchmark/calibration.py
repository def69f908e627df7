"""The confidence model's data and its held-out measurements, shared by fit_confidence.py and bench.py.

Rows are hypotheses: every hypothesis of every frame of every method (Table I's four, seed 0, no
re-ranking) on each scene, with its features (`clipclique.verify.confidence.FEATURES`) and whether its
pose is within the success threshold. Held-out predictions leave one scene out at a time: the
model scoring a scene never saw it.

Frame-level acceptance: a frame's answer is its most confident hypothesis (`inliers.rerank =
confidence`); it is accepted when that confidence reaches a threshold. "Accepted at 95% precision"
is the share of the frames that have a correct hypothesis at all that are accepted, correctly, at
the lowest threshold whose accepted frames are still 95% correct.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from clipclique.config import make_config
from clipclique.errors import ClipcliqueError
from clipclique.pipeline import index_map, localize
from clipclique.pose.distance import pose_errors
from clipclique.pose.stack import Stack
from clipclique.types import Map, Observations, Pose
from clipclique.verify import confidence, verification

BINS = 10  # reliability diagram and ECE: equal-width confidence bins
METHODS = ("xview", "sh", "cliploc", "clipclique")  # Table I's four
PRECISION = 0.95


class CachedFrameLike(Protocol):
    index: int
    observations: Observations
    gt_pose: Pose | None


class SequenceLike(Protocol):
    name: str
    map: Map
    frames: list[CachedFrameLike]


@dataclass
class Rows:
    """One row per hypothesis."""

    features: np.ndarray  # (R, F)
    correct: np.ndarray  # (R,) bool, translation error < success threshold
    scene: np.ndarray  # (R,) str
    method: np.ndarray  # (R,) str
    frame: np.ndarray  # (R,) int, unique over scenes and methods (a frame of one method's run)
    has_correct: np.ndarray  # (F_total,) bool per frame id: some hypothesis of that frame is correct

    def __len__(self) -> int:
        return len(self.correct)

    def take(self, keep: np.ndarray) -> Rows:
        return Rows(self.features[keep], self.correct[keep], self.scene[keep], self.method[keep], self.frame[keep],
                    self.has_correct)


def collect(sequences: list[SequenceLike], methods: tuple[str, ...] = METHODS) -> Rows:
    """Every hypothesis of every method on every sequence's frames with ground truth."""
    features, correct, scene, method, frame, has_correct = [], [], [], [], [], []
    for sequence in sequences:
        for name in methods:
            config = make_config(name)
            index = index_map(sequence.map, config)
            for cached in sequence.frames:
                if cached.gt_pose is None:
                    continue
                frame_id = len(has_correct)
                result = localize(cached.observations, index, config)
                hits = [pose_errors(h.pose, cached.gt_pose)[0] < config.success_threshold_m for h in result.hypotheses]
                has_correct.append(any(hits))
                if not result.hypotheses:
                    continue
                stack = Stack.of(result.hypotheses)
                checked = verification.verify_stack(stack, cached.observations, sequence.map, config.verification)
                evidence = confidence.Evidence(stack, checked, result.similarity, len(cached.observations))
                features.append(confidence.feature_matrix(evidence))
                correct += hits
                scene += [sequence.name] * len(hits)
                method += [name] * len(hits)
                frame += [frame_id] * len(hits)
    if not features:
        raise ClipcliqueError("no hypothesis on any frame with ground truth: nothing to fit a confidence model on")
    return Rows(np.vstack(features), np.array(correct), np.array(scene), np.array(method), np.array(frame),
                np.array(has_correct))


def held_out(rows: Rows) -> np.ndarray:
    """(R,) each row's confidence from a model fitted on the other scenes only."""
    scenes = np.unique(rows.scene)
    if len(scenes) < 2:
        raise ClipcliqueError(f"held-out measurement needs two scenes or more (got {', '.join(scenes)})")
    predicted = np.empty(len(rows))
    for scene in scenes:
        train = rows.scene != scene
        model = confidence.fit(rows.features[train], rows.correct[train], rows.scene[train])
        predicted[~train] = model.probability(rows.features[~train])
    return predicted


def ece(probability: np.ndarray, correct: np.ndarray, bins: int = BINS) -> float:
    """Expected calibration error: bin-size-weighted |accuracy - mean confidence| over equal-width bins."""
    which = np.minimum((probability * bins).astype(int), bins - 1)
    total = 0.0
    for b in range(bins):
        inside = which == b
        if inside.any():
            total += inside.sum() * abs(correct[inside].mean() - probability[inside].mean())
    return total / len(probability)


def frame_answers(rows: Rows, probability: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame with a hypothesis: (frame ids, confidence of its most confident hypothesis, that one is correct)."""
    order = np.lexsort((-probability, rows.frame))
    first = np.r_[True, np.diff(rows.frame[order]) != 0]
    best = order[first]
    return rows.frame[best], probability[best], rows.correct[best]


def acceptance(rows: Rows, probability: np.ndarray, precision: float = PRECISION) -> dict[str, Any]:
    """Frames accepted at `precision`: the lowest threshold keeping it, and the share of frames with a
    correct hypothesis that are correctly accepted; also what `--min-confidence precision` gives."""
    frames, best, right = frame_answers(rows, probability)
    reachable = int(rows.has_correct[np.unique(rows.frame)].sum())
    order = np.argsort(-best, kind="stable")
    hits = np.cumsum(right[order])
    running = hits / np.arange(1, len(order) + 1)
    # Cut only between distinct confidences (a threshold cannot split ties).
    cut_ok = np.r_[best[order][1:] < best[order][:-1], True]
    good = np.flatnonzero((running >= precision) & cut_ok)
    count = int(good.max()) + 1 if len(good) else 0
    fixed = best >= precision
    return {
        "frames": int(len(frames)),
        "frames_with_correct": reachable,
        "threshold": float(best[order][count - 1]) if count else None,
        "accepted": count,
        "accepted_correct": int(hits[count - 1]) if count else 0,
        "share_of_reachable": (int(hits[count - 1]) if count else 0) / reachable if reachable else float("nan"),
        "at_min_confidence": {"accepted": int(fixed.sum()), "correct": int(right[fixed].sum()),
                              "precision": float(right[fixed].mean()) if fixed.any() else float("nan"),
                              "share_of_reachable": int(right[fixed].sum()) / reachable if reachable else float("nan")},
    }


def measure(rows: Rows, probability: np.ndarray) -> dict[str, Any]:
    """Held-out ECE (all hypotheses, and each frame's answer), acceptance, per scene and method."""
    _, best, right = frame_answers(rows, probability)
    out: dict[str, Any] = {"hypotheses": len(rows), "ece": ece(probability, rows.correct),
                           "ece_answers": ece(best, right), "acceptance": acceptance(rows, probability),
                           "reliability": reliability(probability, rows.correct)}
    out["by_scene"] = {scene: {"ece": ece(probability[rows.scene == scene], rows.correct[rows.scene == scene]),
                               "acceptance": acceptance(rows.take(rows.scene == scene),
                                                        probability[rows.scene == scene])}
                       for scene in np.unique(rows.scene).tolist()}
    out["by_method"] = {m: acceptance(rows.take(rows.method == m), probability[rows.method == m])
                        for m in np.unique(rows.method).tolist()}
    return out


def reliability(probability: np.ndarray, correct: np.ndarray, bins: int = BINS) -> list[dict[str, float]]:
    """Per non-empty bin: mean confidence, accuracy, count."""
    which = np.minimum((probability * bins).astype(int), bins - 1)
    return [{"confidence": float(probability[which == b].mean()), "accuracy": float(correct[which == b].mean()),
             "count": int((which == b).sum())} for b in range(bins) if (which == b).any()]


def plot_reliability(bins: list[dict[str, float]], title: str, path: Path) -> None:
    """Reliability diagram: accuracy against confidence per bin (dot area ~ count), the diagonal ideal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(4.5, 4.5))
    axis.plot([0, 1], [0, 1], color="0.6", linestyle="--", label="perfect calibration")
    counts = np.array([b["count"] for b in bins], float)
    axis.scatter([b["confidence"] for b in bins], [b["accuracy"] for b in bins],
                 s=20 + 300 * counts / counts.max(), color="tab:blue", label="held-out scenes")
    axis.set(xlim=(0, 1), ylim=(0, 1), xlabel="confidence", ylabel="share of poses within 1 m", title=title)
    axis.legend(loc="upper left")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
