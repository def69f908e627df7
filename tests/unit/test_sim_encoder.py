"""The simulated CLIP's documented behaviour: text similarity by shared words, weakly discriminative
images whose contents it reads from the crop's instance image."""

from __future__ import annotations

import numpy as np
import pytest

from clipclique.perception.encoders import Crop
from clipclique.sim.encoder import SimulatedClipEncoder


def _pixels(count: int, side: int = 120, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (side, side + i, 3), dtype=np.uint8) for i in range(count)]


def _showing(pixels: list[np.ndarray], contents: tuple[tuple[int, float], ...], truncated: bool = False) -> list[Crop]:
    """Crops whose instance image holds each (object id, share of the pixels) of `contents`, in row order."""
    crops = []
    for image in pixels:
        ids = np.zeros(image.shape[0] * image.shape[1], np.int32)
        start = 0
        for object_id, share in contents:
            stop = start + round(share * len(ids))
            ids[start:stop] = object_id
            start = stop
        crops.append(Crop(image, ids.reshape(image.shape[:2]), truncated))
    return crops


def test_simulated_text_similarity_follows_shared_words():
    encoder = SimulatedClipEncoder()
    text = encoder.encode_text(["a black office chair", "a purple office chair", "a wooden table"])
    assert text.shape == (3, 512) and text.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(text, axis=1), 1.0, atol=1e-6)
    sim = text @ text.T
    assert sim[0, 1] > 0.75  # two of three content words shared
    assert 0.35 < sim[0, 2] < 0.65  # nothing shared: only the common text direction
    np.testing.assert_array_equal(text, encoder.encode_text(["a black office chair", "a purple office chair",
                                                             "a wooden table"]))


def test_simulated_image_is_weakly_discriminative_like_clip():
    texts = ["a black office chair", "a purple office chair", "a wooden table"]
    encoder = SimulatedClipEncoder({1: texts[0]})
    text = encoder.encode_text(texts)
    sims = encoder.encode_images(_showing(_pixels(20), ((1, 1.0),))) @ text.T
    correct, similar, unrelated = sims.mean(axis=0)
    assert 0.33 < correct < 0.47  # the best similarity sits near 0.4, never near 0.8
    assert correct > similar > unrelated  # ranks right, by small margins
    assert correct - similar < 0.15
    assert (sims.argmax(axis=1) == 0).mean() >= 0.7


def test_simulated_signal_drops_for_small_and_truncated_crops():
    encoder = SimulatedClipEncoder({4: "a wooden table"})
    target = encoder.encode_text(["a wooden table"])[0]

    def mean_sim(side: int, truncated: bool) -> float:
        crops = _showing(_pixels(15, side=side, seed=side), ((4, 1.0),), truncated)
        return float((encoder.encode_images(crops) @ target).mean())
    full, cut, small = mean_sim(128, False), mean_sim(128, True), mean_sim(24, False)
    assert full > cut + 0.1 and full > small + 0.2
    assert encoder.signal((24, 24, 3), False) == pytest.approx(0.45 * 24 / 96)


def test_simulated_crop_context_pulls_towards_neighbours():
    encoder = SimulatedClipEncoder({1: "a black office chair", 2: "a white desk", 3: "a white wall"})
    chair, desk = encoder.encode_text(["a black office chair", "a white desk"])
    pixels = _pixels(30)
    alone = encoder.encode_images(_showing(pixels, ((1, 1.0),)))
    crowded = encoder.encode_images(_showing(pixels, ((1, 0.5), (2, 0.4), (0, 0.1))))
    assert (encoder.contents(_showing(pixels, ((1, 0.5), (2, 0.4), (0, 0.1)))[0])[0]
            == (None, pytest.approx(0.1, abs=0.01)))
    assert encoder.contents(Crop(pixels[0])) == ((None, 1.0),)  # no instance image: background alone
    assert (alone @ chair).mean() > (crowded @ chair).mean() + 0.02
    assert (crowded @ desk).mean() > (alone @ desk).mean() + 0.1
    assert ((crowded @ chair) > (crowded @ desk)).mean() > 0.6  # the larger share still tends to win


def test_simulated_images_are_deterministic_and_depend_on_content():
    crops = _showing(_pixels(2), ((7, 1.0),))
    first = SimulatedClipEncoder({7: "a lamp"}).encode_images(crops)
    np.testing.assert_array_equal(first, SimulatedClipEncoder({7: "a lamp"}).encode_images(crops))
    other = SimulatedClipEncoder({7: "a red sofa"}).encode_images(crops)  # same pixels, another object
    assert float(np.mean(np.sum(first * other, axis=1))) < 0.99
    assert abs(float(first[0] @ first[1])) < 0.5  # different pixels, different noise
    assert SimulatedClipEncoder().encode_images([]).shape == (0, 512)
    with pytest.raises(ValueError, match="scene"):  # crops need the descriptions of their scene
        SimulatedClipEncoder().encode_images(crops)
