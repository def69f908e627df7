"""Soft classes: class distributions in the map file (schema 2, schema 1 still read) and their use by the
class term and the map's Semantic Histograms (`similarity.soft_classes`, off by default)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from clipclique.config import make_config
from clipclique.descriptors.similarity import soft_class_similarity
from clipclique.errors import MapFileError
from clipclique.io.mapfile import load_map, save_map
from clipclique.pipeline import index_map, localize
from clipclique.types import Ellipsoids, Map, Observations


def make_map() -> Map:
    """Five landmarks of two classes."""
    rng = np.random.default_rng(3)
    ellipsoids = Ellipsoids(rng.uniform(-3, 3, (5, 3)), rng.uniform(0.05, 1.0, (5, 3)),
                            np.repeat(np.eye(3)[None], 5, axis=0))
    return Map(ellipsoids, np.arange(5) % 2, ["chair", "table"], [f"a chair number {i}" for i in range(5)],
               np.arange(5) + 10,
               provenance={"source": {"name": "test"}})


def rewrite(path, **changes) -> None:
    """Rewrite some arrays of an .npz map file."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    arrays.update(changes)
    np.savez(path, **arrays)


def with_distributions(map: Map, rows: np.ndarray) -> Map:
    return dataclasses.replace(map, class_distributions=rows)


def test_distributions_round_trip_and_a_schema_1_file_still_loads(tmp_path):
    map = with_distributions(make_map(), np.array([[0.7, 0.3], [0, 1], [1, 0], [0.2, 0.8], [1, 0]]))
    path = tmp_path / "soft.map.npz"
    save_map(map, path)
    np.testing.assert_array_equal(load_map(path).class_distributions, map.class_distributions)
    old = tmp_path / "old.map.npz"
    save_map(make_map(), old)
    with np.load(old) as data:
        header = json.loads(str(data["header"][()]))
    header["schema_version"] = 1
    rewrite(old, header=np.array(json.dumps(header)))
    assert load_map(old).class_distributions is None


@pytest.mark.parametrize("rows, problem", [
    (np.full((5, 3), 1 / 3), "should be numbers of shape \\(5, 2\\)"),
    (np.full((5, 2), 0.6), "rows must sum to 1"),
    (np.array([[1.5, -0.5]] * 5), "finite and non-negative"),
])
def test_bad_distributions_refused(tmp_path, rows, problem):
    with pytest.raises(MapFileError, match=problem):
        save_map(with_distributions(make_map(), rows), tmp_path / "x.map.npz")


def room() -> tuple[Map, Observations]:
    """Six landmarks of three classes and the same objects observed from the identity pose."""
    rng = np.random.default_rng(4)
    centers = rng.uniform(-1.5, 1.5, (6, 3))
    ellipsoids = Ellipsoids(centers, np.full((6, 3), 0.2), np.repeat(np.eye(3)[None], 6, axis=0))
    map = Map(ellipsoids, np.array([0, 1, 2, 0, 1, 2]), ["cup", "bottle", "chair"], ["x"] * 6, np.arange(6))
    observations = Observations(ellipsoids, np.array([0, 1, 2, 0, 1, 2]), None, np.arange(6), np.arange(6))
    return map, observations


def test_one_hot_distributions_change_nothing_and_uncertain_ones_soften_the_class_term():
    map, observations = room()
    hard = make_config("clipclique")  # no CLIP embeddings here: Semantic Histograms and the class term
    soft = make_config("clipclique", overrides=["similarity.soft_classes=true"])
    baseline = localize(observations, index_map(map, hard), hard).similarity
    one_hot = with_distributions(map, np.eye(3)[map.class_ids])
    np.testing.assert_allclose(localize(observations, index_map(one_hot, soft), soft).similarity, baseline, atol=1e-12)
    # off: unused
    assert localize(observations, index_map(one_hot, hard), hard).similarity.tolist() == baseline.tolist()
    unsure = one_hot.class_distributions.copy()
    unsure[0] = [0.6, 0.4, 0.0]  # landmark 0: a cup, maybe a bottle
    index = index_map(with_distributions(map, unsure), soft)
    result = localize(observations, index, soft)
    classes = soft_class_similarity(observations.class_ids, index.class_kernel, index.class_distributions)
    # the expected kernel: cup 0.6 * 1 + 0.4 * 0.6 (the look-alike weight), bottle 0.6 * 0.6 + 0.4 * 1
    assert classes[0, 0] == pytest.approx(0.84) and classes[1, 0] == pytest.approx(0.76)
    assert result.similarity[1, 0] > baseline[1, 0]  # the bottle observation now also finds landmark 0
