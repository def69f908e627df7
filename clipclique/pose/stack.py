"""A frame's hypotheses as stacked arrays, from the pose fits through refinement, verification and confidence.

A re-ranked frame fits fifty poses or more and keeps top_n: a `Hypothesis` object built for each, and its
arrays gathered back at every later stage, cost more than those stages' arithmetic. The pool travels as one
`Stack` instead, and only the hypotheses a frame keeps become `Hypothesis` objects (`Stack.hypotheses`).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import accumulate

import numpy as np
from numba import njit

from clipclique.types import Hypothesis, Pose


@dataclass(kw_only=True)
class Stack:
    """B hypotheses, row b of each array; their correspondences one after another in `pairs`."""

    rotations: np.ndarray  # (B, 3, 3) camera-to-map
    translations: np.ndarray  # (B, 3)
    pairs: np.ndarray  # (M, 2) int (observation, landmark), hypothesis after hypothesis
    counts: np.ndarray  # (B,) int64, how many pairs each holds
    scores: np.ndarray  # (B,) the ranking score (Hypothesis.score)
    conditioning: np.ndarray  # (B,) Hypothesis.conditioning, NaN where not measured

    def __len__(self) -> int:
        return len(self.counts)

    def starts(self) -> np.ndarray:
        """(B,) where each hypothesis's pairs begin."""
        return np.cumsum(self.counts) - self.counts

    def owners(self) -> np.ndarray:
        """(M,) the hypothesis each pair belongs to."""
        return np.repeat(np.arange(len(self)), self.counts)

    def take(self, rows: np.ndarray) -> Stack:
        """The hypotheses `rows` (int, in that order), their pairs gathered with them."""
        rows = np.asarray(rows, np.int64)
        counts = self.counts[rows]
        gather = np.repeat(self.starts()[rows] - (np.cumsum(counts) - counts), counts) + np.arange(counts.sum())
        return Stack(rotations=self.rotations[rows], translations=self.translations[rows], pairs=self.pairs[gather],
                     counts=counts, scores=self.scores[rows], conditioning=self.conditioning[rows])

    def hypotheses(self, rows: np.ndarray | None = None, verification: list[float] | None = None,
                   confidence: list[float] | None = None) -> list[Hypothesis]:
        """`Hypothesis` objects of `rows` (None: all, in order), with their verification scores and confidences
        where given (one per row of `rows`). Read as Python numbers and views, row by row: a frame keeps five of
        fifty, and a numpy gather per field cost more than the objects."""
        counts, scores, conditioning = self.counts.tolist(), self.scores.tolist(), self.conditioning.tolist()
        starts = [0, *accumulate(counts)]
        chosen = range(len(counts)) if rows is None else rows.tolist()
        verified = [None] * len(chosen) if verification is None else verification
        confident = [None] * len(chosen) if confidence is None else confidence
        return [Hypothesis(Pose(self.rotations[b], self.translations[b]), self.pairs[starts[b]: starts[b + 1]],
                           scores[b], conditioning[b], checked, sure)
                for b, checked, sure in zip(chosen, verified, confident)]

    @staticmethod
    def of(hypotheses: list[Hypothesis]) -> Stack:
        """The stack of a list of hypotheses (a library caller's own, or a frame's result)."""
        return Stack(rotations=np.array([h.pose.rotation for h in hypotheses], np.float64).reshape(-1, 3, 3),
                     translations=np.array([h.pose.translation for h in hypotheses], np.float64).reshape(-1, 3),
                     pairs=np.concatenate([np.asarray(h.correspondences).reshape(-1, 2) for h in hypotheses]
                                          or [np.zeros((0, 2), np.int64)]),
                     counts=np.array([len(h.correspondences) for h in hypotheses], np.int64),
                     scores=np.array([h.score for h in hypotheses], np.float64),
                     conditioning=np.array([h.conditioning for h in hypotheses], np.float64))

    @staticmethod
    def joined(stacks: list[Stack]) -> Stack:
        """The stacks one after another (none: an empty stack)."""
        if len(stacks) == 1:
            return stacks[0]
        return Stack(rotations=np.concatenate([s.rotations for s in stacks] or [np.zeros((0, 3, 3))]),
                     translations=np.concatenate([s.translations for s in stacks] or [np.zeros((0, 3))]),
                     pairs=np.concatenate([s.pairs for s in stacks] or [np.zeros((0, 2), np.int64)]),
                     counts=np.concatenate([s.counts for s in stacks] or [np.zeros(0, np.int64)]),
                     scores=np.concatenate([s.scores for s in stacks] or [np.zeros(0)]),
                     conditioning=np.concatenate([s.conditioning for s in stacks] or [np.zeros(0)]))


def alike(poses: np.ndarray, pairs: np.ndarray,
          starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which of R items are identical (the same float bits, so -0 and +0 differ): item r is row r of `poses` (R, P)
    float (P = 0: pairs alone) and the pairs[starts[r]: starts[r] + counts[r]] of `pairs` (M, 2) or (M,) int. (R,)
    each item's group, numbered in order of first appearance, and (G,) each group's first item: the work of each group
    done once (`alike_spans`)."""
    bits = np.ascontiguousarray(poses, np.float64).view(np.int64)
    values = np.ascontiguousarray(pairs, np.int64)
    width = values.shape[1] if values.ndim == 2 else 1  # the pairs' numbers one after another
    return alike_spans(bits, values.reshape(-1), width * np.asarray(starts, np.int64),
                       width * np.asarray(counts, np.int64))


@njit(cache=True)
def alike_spans(bits, values, starts, counts):
    """`alike` of poses as their bits (int64) and spans of `values` (1-D int: item r's are values[starts[r]:
    starts[r] + counts[r]]): each item against the first item of every group before it (a frame's fifty hypotheses:
    a few thousand comparisons, most ended by the first number), number by number in place: a row or span handed to
    a helper is a view, and each view costs two atomic reference-count operations."""
    group, firsts = np.empty(len(counts), np.int64), np.empty(len(counts), np.int64)
    found = 0
    for r in range(len(counts)):
        group[r] = -1
        for g in range(found):
            f = firsts[g]
            if counts[f] != counts[r]:
                continue
            alike = True
            for i in range(bits.shape[1]):
                if bits[f, i] != bits[r, i]:
                    alike = False
                    break
            for i in range(counts[r] if alike else 0):
                if values[starts[f] + i] != values[starts[r] + i]:
                    alike = False
                    break
            if alike:
                group[r] = g
                break
        if group[r] < 0:
            group[r], firsts[found] = found, r
            found += 1
    return group, firsts[:found].copy()
