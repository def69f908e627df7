"""The simulated CLIP (`SimulatedClipEncoder`, name "simulated-clip") stands in for CLIP on
synthetic data whose true object descriptions are known. Its model, in unit vectors of R^D:

- Text: every content word w has a fixed random direction h(w) (seeded by a hash of the word);
  a description's text embedding is normalize(g + normalize(sum_w h(w))), where g is one
  direction shared by all texts. So descriptions sharing words are similar ("a black office
  chair" . "a purple office chair" ~ 0.83) and unrelated ones still sit near 0.5, as CLIP's
  text embeddings of object phrases do.
- Image: a crop shows its object and whatever else falls in its box: each labelled thing of the
  frame's instance image inside the box (`Crop.instances`), with its description (the scene's,
  given at construction) and its share of the box's pixels; background, structure and objects
  without a description count as the shared direction g. Its embedding is normalize(q * c + n), c = normalize(sum of
  share * text(description)), n a random unit vector seeded by (crop bytes, contents, seed);
  an object filling its box has cosine about q / sqrt(1 + q^2) with its own text, and every
  neighbour in the box pulls the embedding towards that neighbour's text, as the context of
  a crop does to real CLIP. The signal q = q_max * size * visible:
  size = min(1, sqrt(area / 96^2)) weakens small crops, visible = 0.6 for an object cut by the
  image border. With q_max = 0.45 the correct similarity is at best ~0.41 and its margin over a
  wrong description shrinks with shared words: CLIP as the paper reports it, weakly
  discriminative (best similarities near 0.4 where Semantic Histograms reach 0.8).
  A false detection's box holds no object of its own, only what lies behind it.

Everything is deterministic: the same crop, contents and seed give the same embedding.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Mapping, Sequence

import numpy as np

from clipclique.perception.detectors import id_counts
from clipclique.perception.encoders import Crop, normalize

SIMULATED_NAME = "simulated-clip"
_STOP_WORDS = frozenset({"a", "an", "the", "of", "on", "in", "with", "and", "photo", "this", "is"})


def _seed(*parts: bytes | str | np.ndarray) -> int:
    """A 64-bit seed hashed from `parts` (an array: its C-order bytes, hashed without copying them)."""
    digest = hashlib.blake2b(digest_size=8)
    for part in parts:
        digest.update(part.encode() if isinstance(part, str) else part)
        digest.update(b"\0")
    return int.from_bytes(digest.digest(), "little")


class SimulatedClipEncoder:
    """A documented stand-in for CLIP on synthetic data (see the module docstring)."""

    simulated = True

    def __init__(self, descriptions: Mapping[int, str] | None = None, dim: int = 512, q_max: float = 0.45,
                 ref_side: float = 96.0, truncated_visibility: float = 0.6, seed: int = 0) -> None:
        self.name = SIMULATED_NAME
        # dataset object id -> description, the scene's; None: bound to no scene (text only)
        self.descriptions = None if descriptions is None else dict(descriptions)
        self.dim = dim
        self.q_max = q_max
        self.ref_side = ref_side
        self.truncated_visibility = truncated_visibility
        self.seed = seed
        self._shared = self._direction("<shared>")
        # text -> embedding: a run embeds the map's few descriptions again and again
        self._texts: dict[str, np.ndarray] = {}

    def _direction(self, key: str) -> np.ndarray:
        rng = np.random.default_rng(_seed(str(self.seed), key))
        return normalize(rng.standard_normal(self.dim))

    def _text(self, text: str) -> np.ndarray:
        if text not in self._texts:
            words = [w for w in re.findall(r"[a-z0-9]+", text.lower()) if w not in _STOP_WORDS]
            content = normalize(np.sum([self._direction(w) for w in words], axis=0)) if words else 0.0
            self._texts[text] = normalize(self._shared + content)
        return self._texts[text]

    def encode_text(self, texts: list[str]) -> np.ndarray:
        return np.stack([self._text(t) for t in texts]) if texts else np.zeros((0, self.dim), np.float32)

    def signal(self, crop_shape: tuple[int, ...], truncated: bool) -> float:
        """q of the module docstring: weaker for small and for border-cut crops."""
        size = min(1.0, float(np.sqrt(crop_shape[0] * crop_shape[1])) / self.ref_side)
        return self.q_max * size * (self.truncated_visibility if truncated else 1.0)

    def contents(self, crop: Crop) -> tuple[tuple[str | None, float], ...]:
        """What the crop shows: (description, share of its pixels) per object id of its instance image
        (None: unlabelled, structure, or no description); all background without an instance image."""
        if self.descriptions is None:
            raise ValueError("the simulated CLIP embeds crops of a scene it knows the descriptions of: "
                             "SimulatedClipEncoder(scene descriptions), or load_encoder('simulated', scene=sequence)")
        if crop.instances is None:
            return ((None, 1.0),)
        ids, counts = id_counts(crop.instances)
        return tuple(zip([self.descriptions.get(i) for i in ids.tolist()], (counts / counts.sum()).tolist()))

    def encode_images(self, crops: Sequence[Crop]) -> np.ndarray:
        if not crops:
            return np.zeros((0, self.dim), np.float32)
        out = []
        for crop in crops:
            contents = self.contents(crop)
            pixels = np.ascontiguousarray(crop.pixels)
            target = normalize(sum(share * (self._shared if d is None else self._text(d)) for d, share in contents))
            rng = np.random.default_rng(_seed(str(self.seed), pixels, str(pixels.shape), repr(contents)))
            noise = normalize(rng.standard_normal(self.dim))
            out.append(self.signal(pixels.shape, crop.truncated) * target + noise)
        return normalize(np.stack(out))
