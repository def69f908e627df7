"""`clipclique-loc align A B C`: three maps aligned around the cycle A -> B -> C -> A, and whether the cycle
closes. Three answers that compose to the identity corroborate each other; one that does not is wrong
somewhere, and the least confident link is the first suspect (issue 38: a confident wrong edge)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from clipclique.pose.distance import rotation_angle

CLOSES_DEG, CLOSES_M = 2.0, 0.05  # a cycle closes when composing its links moves A's landmarks less than this


@dataclass(frozen=True)
class Cycle:
    """How far the composed links are from the identity, and the weakest link."""

    rotation_deg: float
    translation_m: float  # the farthest one of A's landmarks moves under the composition
    weakest: str  # "A into B" of the least confident link
    weakest_confidence: float

    @property
    def closes(self) -> bool:
        return self.rotation_deg <= CLOSES_DEG and self.translation_m <= CLOSES_M

    def line(self) -> str:
        verdict = "closes" if self.closes else f"does not close (limits {CLOSES_DEG:g} deg, {CLOSES_M:g} m)"
        return (f"cycle {verdict}: {self.rotation_deg:.2f} deg, {self.translation_m:.3f} m; weakest link "
                f"{self.weakest} (confidence {self.weakest_confidence:.2f})")


def cycle(documents: list[dict[str, Any]], centers: np.ndarray) -> Cycle | None:
    """The closure of three alignment documents (A into B, B into C, C into A; their best candidates), measured
    on A's landmark `centers`; None when a link found no transform."""
    if any(not document["candidates"] for document in documents):
        return None
    composed = np.eye(4)
    for document in documents:
        composed = np.array(document["candidates"][0]["matrix"]) @ composed
    moved = centers @ composed[:3, :3].T + composed[:3, 3]
    weakest = min(documents, key=lambda document: document["candidates"][0]["confidence"])
    return Cycle(math.degrees(rotation_angle(composed[:3, :3])), float(np.linalg.norm(moved - centers, axis=1).max()),
                 f"{weakest['query_map']} into {weakest['map']}", weakest["candidates"][0]["confidence"])
