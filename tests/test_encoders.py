"""Encoders: the simulated CLIP's documented behaviour, and real open_clip plumbing on random weights."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from clipclique.encoders import ClipEncoder, CropTruth, SimulatedClipEncoder, load_encoder
from clipclique.errors import ClipcliqueError, ModelUnavailableError


def _crops(count: int, side: int = 120, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (side, side + i, 3), dtype=np.uint8) for i in range(count)]


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
    encoder = SimulatedClipEncoder()
    texts = ["a black office chair", "a purple office chair", "a wooden table"]
    text = encoder.encode_text(texts)
    crops = _crops(20)
    sims = encoder.encode_images(crops, [texts[0]] * 20) @ text.T
    correct, similar, unrelated = sims.mean(axis=0)
    assert 0.33 < correct < 0.47  # the best similarity sits near 0.4, never near 0.8
    assert correct > similar > unrelated  # ranks right, by small margins
    assert correct - similar < 0.15
    assert (sims.argmax(axis=1) == 0).mean() >= 0.7


def test_simulated_signal_drops_for_small_and_truncated_crops():
    encoder = SimulatedClipEncoder()
    target = encoder.encode_text(["a wooden table"])[0]
    def mean_sim(side: int, truncated: bool) -> float:
        crops = _crops(15, side=side, seed=side)
        truth = [CropTruth((("a wooden table", 1.0),), truncated)] * 15
        return float((encoder.encode_images(crops, truth) @ target).mean())
    full, cut, small = mean_sim(128, False), mean_sim(128, True), mean_sim(24, False)
    assert full > cut + 0.1 and full > small + 0.2
    assert encoder.signal((24, 24, 3), False) == pytest.approx(0.45 * 24 / 96)


def test_simulated_crop_context_pulls_towards_neighbours():
    encoder = SimulatedClipEncoder()
    chair, desk = encoder.encode_text(["a black office chair", "a white desk"])
    crops = _crops(30)
    alone = encoder.encode_images(crops, ["a black office chair"] * 30)
    crowded = encoder.encode_images(crops, [CropTruth((("a black office chair", 0.5), ("a white desk", 0.4),
                                                        (None, 0.1)))] * 30)
    assert (alone @ chair).mean() > (crowded @ chair).mean() + 0.02
    assert (crowded @ desk).mean() > (alone @ desk).mean() + 0.1
    assert ((crowded @ chair) > (crowded @ desk)).mean() > 0.6  # the larger share still tends to win


def test_simulated_images_are_deterministic_and_depend_on_content():
    crops = _crops(2)
    first = SimulatedClipEncoder().encode_images(crops, ["a lamp", "a lamp"])
    np.testing.assert_array_equal(first, SimulatedClipEncoder().encode_images(crops, ["a lamp", "a lamp"]))
    assert abs(float(first[0] @ first[1])) < 0.5  # different pixels, different noise
    assert SimulatedClipEncoder().encode_images([]).shape == (0, 512)


def test_load_encoder_specs():
    assert load_encoder("none") is None
    assert load_encoder("simulated").simulated
    with pytest.raises(ClipcliqueError, match="--encoder"):
        load_encoder("clip-please")
    with pytest.raises(ModelUnavailableError, match="checkpoint file not found"):
        load_encoder("/nonexistent/weights.pt")


def test_missing_weights_name_the_option(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(ModelUnavailableError, match="--encoder"):
        load_encoder("open_clip:ViT-B-32/laion2b_s34b_b79k")
    with pytest.raises(ModelUnavailableError, match="no pretrained tag"):
        load_encoder("open_clip:ViT-B-32/no-such-tag")


@pytest.fixture(scope="module")
def random_clip():
    """A real ViT-B-32 graph with random weights: the real code path without a download."""
    open_clip = pytest.importorskip("open_clip")
    import torch

    torch.manual_seed(0)
    model, _, preprocess = open_clip.create_model_and_transforms("ViT-B-32", pretrained=None)
    return ClipEncoder(model, preprocess, open_clip.get_tokenizer("ViT-B-32"), "open_clip:ViT-B-32/random",
                       "cpu", batch_size=2)


@pytest.mark.models
def test_real_clip_shapes_norms_and_batching(random_clip):
    crops = _crops(3)
    batched = random_clip.encode_images(crops)
    assert batched.shape == (3, 512) and batched.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(batched, axis=1), 1.0, atol=1e-5)
    one_by_one = np.concatenate([random_clip.encode_images([c]) for c in crops])
    np.testing.assert_allclose(batched, one_by_one, atol=1e-5)
    assert not np.allclose(batched[0], batched[1], atol=1e-3)
    # truth is ignored by real CLIP
    np.testing.assert_allclose(random_clip.encode_images(crops, ["x", "y", "z"]), batched, atol=1e-6)
    text = random_clip.encode_text(["a chair", "a table", "a lamp"])
    assert text.shape == (3, 512)
    np.testing.assert_allclose(np.linalg.norm(text, axis=1), 1.0, atol=1e-5)
    assert random_clip.encode_images([]).shape == (0, 512)


@pytest.mark.models
def test_real_clip_device_placement(random_clip):
    import torch

    assert {p.device.type for p in random_clip.model.parameters()} == {"cpu"}
    if torch.cuda.is_available():
        gpu = ClipEncoder(copy.deepcopy(random_clip.model), random_clip.preprocess, random_clip.tokenizer, "gpu", "cuda")
        assert {p.device.type for p in gpu.model.parameters()} == {"cuda"}
        assert gpu.encode_images(_crops(2)).shape == (2, 512)
