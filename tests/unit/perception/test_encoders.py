"""Encoders: the registry's specs, and real open_clip plumbing on random weights."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from clipclique.backends import load_encoder
from clipclique.errors import ClipcliqueError, ModelUnavailableError
from clipclique.perception.encoders import ClipEncoder, Crop


def _crops(count: int, side: int = 120, seed: int = 0) -> list[Crop]:
    rng = np.random.default_rng(seed)
    return [Crop(rng.integers(0, 256, (side, side + i, 3), dtype=np.uint8)) for i in range(count)]


def test_load_encoder_specs():
    assert load_encoder("none") is None
    assert load_encoder("simulated").simulated
    assert load_encoder("simulated-clip").descriptions is None  # text only: no scene to read crops of
    with pytest.raises(ClipcliqueError, match="--encoder"):
        load_encoder("clip-please")
    with pytest.raises(ModelUnavailableError, match="checkpoint file not found"):
        load_encoder("/nonexistent/weights.pt")


def test_missing_weights_name_the_option(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(ModelUnavailableError, match="--encoder"):
        load_encoder("open_clip:ViT-B-32/laion2b_s34b_b79k")


@pytest.mark.models
def test_an_unknown_pretrained_tag_is_named(monkeypatch):
    pytest.importorskip("open_clip")  # without it the error is the missing extra, checked above
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
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
    # the instance image is ignored by real CLIP
    shown = [Crop(c.pixels, np.ones(c.pixels.shape[:2], np.int32), True) for c in crops]
    np.testing.assert_allclose(random_clip.encode_images(shown), batched, atol=1e-6)
    text = random_clip.encode_text(["a chair", "a table", "a lamp"])
    assert text.shape == (3, 512)
    np.testing.assert_allclose(np.linalg.norm(text, axis=1), 1.0, atol=1e-5)
    assert random_clip.encode_images([]).shape == (0, 512)


@pytest.mark.models
def test_real_clip_device_placement(random_clip):
    import torch

    assert {p.device.type for p in random_clip.model.parameters()} == {"cpu"}
    if torch.cuda.is_available():
        gpu = ClipEncoder(copy.deepcopy(random_clip.model), random_clip.preprocess, random_clip.tokenizer, "gpu",
                          "cuda")
        assert {p.device.type for p in gpu.model.parameters()} == {"cuda"}
        assert gpu.encode_images(_crops(2)).shape == (2, 512)
