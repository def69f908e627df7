"""Results held within stated tolerances, not bit for bit: a run's decisions frame by frame (golden files in
tests/golden/, and any two runs that should agree, such as one sequence read two ways).

Numbers move in their last bits between machines and library versions (BLAS kernels, numpy's SIMD loops);
decisions do not. So poses must agree within `POSE_M` and `POSE_RAD`, scores and confidences within `RTOL` and
`ATOL`, and counts, correspondences and failure kinds exactly. A tie decided by the last bit moves a frame's
correspondences and its pose together, so `MAX_FRAMES_DIFFERING` frames of a run may differ in anything; the
success rate at every threshold must still be within `SUCCESS_FRAMES` frames of the golden figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

POSE_M = 1e-6  # metres: translations
POSE_RAD = 1e-6  # radians: the angle between two rotations
RTOL, ATOL = 1e-9, 1e-12  # scores, conditioning, verification, confidence
MAX_FRAMES_DIFFERING = 1
SUCCESS_FRAMES = 1
THRESHOLDS_M = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0)  # wider than any table's, so a new threshold is covered
EXACT = ("index", "failure_kind", "detections", "observations", "candidates", "num_cliques")
SCALARS = ("score", "conditioning", "verification", "confidence")
KERNEL_RTOL = 1e-12  # a compiled kernel against its numpy reference: rounding, a few ulps of the largest term


def decisions(document: dict[str, Any]) -> list[dict[str, Any]]:
    """What a results.json decided, frame by frame: counts, failure kind, errors, and each hypothesis's pose
    (translation, rotation), scores and correspondences. No timings, paths, wording or threshold keys."""
    frames = []
    for frame in document["frames"]:
        evaluation = frame["evaluation"]
        frames.append({
            **{key: frame[key] for key in EXACT},
            "translation_error_m": evaluation["translation_error_m"],
            "rotation_error_deg": evaluation["rotation_error_deg"],
            "hypotheses": [{
                "translation": [row[3] for row in hypothesis["pose"][:3]],
                "rotation": [row[:3] for row in hypothesis["pose"][:3]],
                **{key: hypothesis[key] for key in SCALARS},
                "correspondences": hypothesis["correspondences"],
            } for hypothesis in frame["hypotheses"]],
        })
    return frames


@dataclass(frozen=True)
class Comparison:
    """How a run's decisions meet the expected ones: each differing frame with its first difference, and the
    success counts at `THRESHOLDS_M` (expected, found)."""

    frames: int
    differing: dict[int, str]
    success: dict[float, tuple[int, int]]

    @property
    def holds(self) -> bool:
        return (len(self.differing) <= MAX_FRAMES_DIFFERING
                and all(abs(a - b) <= SUCCESS_FRAMES for a, b in self.success.values()))

    def report(self) -> str:
        """One line per differing frame and per moved success figure ("" when nothing moved)."""
        lines = [f"frame {index}: {difference}" for index, difference in self.differing.items()]
        lines += [f"within {t:g} m: {a} -> {b} of {self.frames} frames"
                  for t, (a, b) in self.success.items() if a != b]
        return "\n".join(lines)


def compare(expected: list[dict[str, Any]], found: list[dict[str, Any]]) -> Comparison:
    """`found` frame by frame against `expected` (both `decisions`), which must cover the same frames."""
    indices = [frame["index"] for frame in expected], [frame["index"] for frame in found]
    if indices[0] != indices[1]:
        raise AssertionError(f"the runs cover other frames: {indices[0][:5]}... against {indices[1][:5]}...")
    differing = {a["index"]: difference for a, b in zip(expected, found) if (difference := frame_difference(a, b))}
    success = {t: (successes(expected, t), successes(found, t)) for t in THRESHOLDS_M}
    return Comparison(len(expected), differing, success)


def successes(frames: list[dict[str, Any]], threshold_m: float) -> int:
    """Frames whose top-1 pose is within `threshold_m` of the ground truth (a frame without a pose fails)."""
    return sum(frame["translation_error_m"] is not None and frame["translation_error_m"] < threshold_m
               for frame in frames)


def frame_difference(a: dict[str, Any], b: dict[str, Any]) -> str | None:
    """The first way frame `b` departs from `a` beyond the tolerances, or None."""
    for key in EXACT:
        if a[key] != b[key]:
            return f"{key} {a[key]!r} -> {b[key]!r}"
    if len(a["hypotheses"]) != len(b["hypotheses"]):
        return f"{len(a['hypotheses'])} -> {len(b['hypotheses'])} hypotheses"
    for rank, (x, y) in enumerate(zip(a["hypotheses"], b["hypotheses"]), start=1):
        if difference := hypothesis_difference(x, y):
            return f"hypothesis {rank}: {difference}"
    for key, tolerance in (("translation_error_m", POSE_M), ("rotation_error_deg", math.degrees(POSE_RAD))):
        if not _close(a[key], b[key], 0.0, tolerance):
            return f"{key} {a[key]} -> {b[key]}"
    return None


def hypothesis_difference(a: dict[str, Any], b: dict[str, Any]) -> str | None:
    """The first way hypothesis `b` departs from `a`: correspondences exactly, the pose and scores within
    tolerance."""
    if a["correspondences"] != b["correspondences"]:
        return "other correspondences"
    moved = float(np.abs(np.subtract(a["translation"], b["translation"])).max())
    if not moved <= POSE_M:
        return f"translation moved {moved:.3g} m"
    turned = rotation_angle(np.asarray(a["rotation"]), np.asarray(b["rotation"]))
    if not turned <= POSE_RAD:
        return f"rotation turned {turned:.3g} rad"
    for key in SCALARS:
        if not _close(a[key], b[key], RTOL, ATOL):
            return f"{key} {a[key]!r} -> {b[key]!r}"
    return None


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle of a^T b in radians, accurate near 0 (from the skew part, not the trace's arccos)."""
    relative = a.T @ b
    skew = np.array([relative[2, 1] - relative[1, 2], relative[0, 2] - relative[2, 0], relative[1, 0] - relative[0, 1]])
    return float(math.atan2(0.5 * np.linalg.norm(skew), 0.5 * (np.trace(relative) - 1.0)))


def _close(a: float | None, b: float | None, rtol: float, atol: float) -> bool:
    if a is None or b is None:
        return a is b
    return abs(a - b) <= atol + rtol * abs(a)


def assert_close(ours: np.ndarray, theirs: np.ndarray, atol: float | None = None) -> None:
    """A kernel's array against its numpy reference: the same shape; integers and booleans equal, floats (either
    side) within KERNEL_RTOL and KERNEL_RTOL of the array's largest finite magnitude (or `atol`), NaN where NaN
    and infinities alike. Types are the caller's to check (a reference's empty sum may be an integer 0)."""
    assert ours.shape == theirs.shape, (ours.shape, theirs.shape)
    if ours.dtype.kind != "f" and theirs.dtype.kind != "f":
        np.testing.assert_array_equal(ours, theirs)
        return
    theirs = np.asarray(theirs, np.float64)
    finite = np.abs(theirs[np.isfinite(theirs)])
    atol = KERNEL_RTOL * max(1.0, float(finite.max(initial=0.0))) if atol is None else atol
    np.testing.assert_allclose(ours, theirs, rtol=KERNEL_RTOL, atol=atol)
