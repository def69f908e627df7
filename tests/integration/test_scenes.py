"""The realistic demo scenes (demo_apartment, demo_desk) measured by clipclique.benchmark.scene_stats against
docs/REAL_SCENES.md, on a few frames of each (bands wide enough for so few frames)."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest

from clipclique.benchmark import scene_stats
from clipclique.resolve import default_detector, open_scene
from clipclique.sim.demo import DEMO_SCENES, generate
from clipclique.sim.detectors import read_lookalikes

FRAMES = {"demo_apartment": 20, "demo_desk": 16}  # spread over the whole walk, full resolution


@pytest.fixture(scope="session")
def scenes(demo_data) -> dict[str, scene_stats.SceneStats]:
    """Both scenes generated with fewer frames of the same walk, and their statistics."""
    return {name: scene_stats.measure(open_scene(name, demo_data(name, frames=frames, size=None)))
            for name, frames in FRAMES.items()}


def test_apartment_map_is_sparse_like_a_scannet_apartment(scenes):
    stats = scenes["demo_apartment"]
    assert stats.objects == 45 and 28 <= stats.classes <= 34
    degrees = np.bincount(stats.degrees)
    assert 0.38 <= degrees[0] / stats.objects <= 0.55  # real: 47% isolated
    assert 5 <= len(degrees) <= 8 and degrees[1:].sum() == stats.objects - degrees[0]
    assert np.allclose(stats.extent, (7.3, 7.8, 2.1), atol=0.5)


def test_apartment_frames_see_few_objects_in_part(scenes):
    stats = scenes["demo_apartment"]
    assert 4 <= np.median(stats.observations) <= 11 and stats.observations.max() >= 10  # real: 3-17, median 9
    assert 0.25 <= stats.isolated_observations <= 0.6  # real: 47%
    median, p90 = np.percentile(stats.offsets, [50, 90])
    assert 0.12 <= median <= 0.3 and p90 >= 0.45  # real: 0.18, 0.80: partial views move centres
    assert 0.2 <= np.mean(stats.offsets > 0.3) <= 0.45  # real: 32%
    assert stats.detector == "ground-truth" and stats.miss_rate == 0 and stats.false_positives == 0


def test_desk_map_is_dense_clutter_of_coco_classes(scenes, tmp_path):
    stats = scenes["demo_desk"]
    assert stats.objects == 47 and stats.classes == 19
    assert 14 <= np.median(stats.degrees) <= 21 and stats.degrees.max() >= 22 and stats.degrees.min() == 0
    assert np.allclose(stats.extent, (5.5, 3.4, 1.0), atol=0.4)
    generate(tmp_path, "demo_desk", dataclasses.replace(DEMO_SCENES["demo_desk"], num_frames=1, width=80, height=60))
    counts = Counter(open_scene(str(tmp_path)).object_classes().values())
    assert {k: counts[k] for k in ("cup", "book", "chair", "mouse", "tv", "vase", "keyboard", "bowl")} == {
        "cup": 8, "book": 7, "chair": 4, "mouse": 3, "tv": 3, "vase": 3, "keyboard": 2, "bowl": 2}
    coco = {"dining table", "bottle", "cell phone", "fork", "knife", "spoon", "scissors", "remote", "laptop",
            "teddy bear", "potted plant"}
    assert set(counts) - {"cup", "book", "chair", "mouse", "tv", "vase", "keyboard", "bowl"} == coco


def test_desk_simulated_yolo_fails_like_the_real_one(scenes):
    stats = scenes["demo_desk"]
    assert stats.detector == "simulated-yolo"
    assert 20 <= np.median(stats.observations_near) <= 34  # real: about 26 objects in view within 3.5 m
    assert 0.6 <= stats.miss_rate <= 0.85  # real: about 70%
    assert 0.12 <= stats.false_positive_share <= 0.32  # real: 21%
    assert 0.2 <= stats.confusion_share <= 0.5  # real: 34%
    table = read_lookalikes()
    assert all(detected in {other for other, _ in table[true]} for true, detected in stats.confusions)


def test_scenes_name_their_default_detector(tmp_path):
    for name, expected in (("demo_apartment", "gt"), ("demo_desk", "simulated-yolo"), ("demo", "simulated")):
        folder = tmp_path / "demo" / name
        folder.mkdir(parents=True)
        generate(folder, name, dataclasses.replace(DEMO_SCENES[name], num_frames=1, width=80, height=60))
        assert default_detector(open_scene(name, tmp_path)) == expected
