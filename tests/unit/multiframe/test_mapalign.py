"""Map-to-map alignment on generated cases: recovered transforms, no confident answer for unrelated maps,
ambiguity among copies, vocabularies matched by name, a small submap in a large map, the g2o edge."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.config import make_config
from clipclique.multiframe.mapalign import g2o_edge, rotation_sigma, shared_vocabulary, supported
from clipclique.pipeline import align_maps
from clipclique.pose.distance import rotation_angle
from clipclique.sim.poses import random_rotation
from clipclique.sim.synthetic import duplicate_rooms, synthetic_map
from clipclique.types import Map, Pose

CONFIG = make_config("clipclique")


def moved(map: Map, truth: Pose, rng: np.random.Generator, noise: float = 0.005) -> Map:
    """`map` in the query map's frame (`truth` takes it back), centres jittered."""
    out = map.transformed(truth.inverse())
    out.ellipsoids.centers = out.ellipsoids.centers + rng.normal(scale=noise, size=out.ellipsoids.centers.shape)
    return out


def errors(pose: Pose, truth: Pose, query: Map) -> tuple[float, float]:
    """(metres: the farthest a query landmark lands from where the truth puts it, degrees: rotation error).
    The translation of the matrix itself depends on where the query map's origin lies (0.3 degrees off
    moves an origin 10 m away by 5 cm), the landmarks' displacement does not."""
    centers = query.ellipsoids.centers
    return (float(np.linalg.norm(pose.apply(centers) - truth.apply(centers), axis=1).max()),
            math.degrees(rotation_angle(pose.rotation.T @ truth.rotation)))


@pytest.mark.parametrize("seed", range(4))
def test_two_overlapping_parts_moved_by_a_known_transform(seed):
    rng = np.random.default_rng(seed)
    room = synthetic_map(rng, 40)
    x = room.ellipsoids.centers[:, 0]
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    query = moved(room.subset(np.flatnonzero(x < 3.2)), truth, rng, noise=0.005 if seed else 0.0)
    alignment = align_maps(query, room.subset(np.flatnonzero(x > 1.8)), CONFIG)
    best = alignment.candidates[0]
    translation, rotation = errors(best.pose, truth, query)
    assert translation < (0.05 if seed else 1e-9) and rotation < 1.0
    if not seed:  # noise-free: the rotation itself (an angle's arccos cannot resolve less than ~1e-6 degrees)
        np.testing.assert_allclose(best.pose.rotation, truth.rotation, rtol=0, atol=1e-12)
    assert not alignment.ambiguous and best.confidence > 0.5
    pairs = best.correspondences
    assert np.array_equal(query.instance_ids[pairs[:, 0]],
                          room.subset(np.flatnonzero(x > 1.8)).instance_ids[pairs[:, 1]])


@pytest.mark.parametrize("method", ["sh", "xview", "cliploc", "clipclique-paper"])
def test_every_method_aligns_maps_by_centres(method):
    """Maps have no image: the RANSAC methods' overlap verification (the preset) would stop on it."""
    rng = np.random.default_rng(7)
    room = synthetic_map(rng, 40)
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    query = moved(room.subset(np.arange(25)), truth, rng)
    assert make_config(method).inliers.verification == "overlap"
    best = align_maps(query, room, make_config(method)).candidates[0]
    translation, rotation = errors(best.pose, truth, query)
    assert translation < 0.05 and rotation < 1.0


def test_unrelated_maps_give_no_confident_alignment():
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        alignment = align_maps(synthetic_map(rng, 25), synthetic_map(rng, 40), CONFIG)
        assert max((c.confidence for c in alignment.candidates), default=0.0) < 0.5, seed


def test_a_part_of_a_room_in_ten_copies_is_ambiguous():
    rng = np.random.default_rng(7)
    room = synthetic_map(rng, 40)
    near = np.argsort(np.linalg.norm(room.ellipsoids.centers - room.ellipsoids.centers[0], axis=1))[:12]
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    alignment = align_maps(moved(room.subset(near), truth, rng), duplicate_rooms(room, 10), CONFIG)
    assert alignment.ambiguous
    assert len(alignment.competitors) >= 5  # every reported candidate is one copy
    shifts = sorted(round(c.pose.translation[0] - alignment.candidates[0].pose.translation[0], 1)
                    for c in alignment.candidates)
    assert len(set(shifts)) == len(shifts)  # distinct copies, not one copy five times
    assert all(c.confidence < 0.5 for c in alignment.candidates)


def test_eight_objects_against_five_thousand():
    rng = np.random.default_rng(1)
    big = synthetic_map(rng, 5000, num_classes=30, room=(60.0, 60.0, 2.0))
    near = np.argsort(np.linalg.norm(big.ellipsoids.centers - big.ellipsoids.centers[17], axis=1))[:8]
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    align_maps(moved(big.subset(near), truth, rng), big, CONFIG)  # compile
    start = time.perf_counter()
    alignment = align_maps(moved(big.subset(near), truth, rng), big, CONFIG)
    assert time.perf_counter() - start < 10.0
    translation, rotation = errors(alignment.candidates[0].pose, truth, big.subset(near).transformed(truth.inverse()))
    assert translation < 0.05 and rotation < 1.0 and alignment.candidates[0].confidence > 0.8


def test_vocabularies_matched_by_name_and_synonym():
    names, ids, matched = shared_vocabulary(["Sofa", "monitor", "lamp", "chair"], ["chair", "couch", "tv"])
    assert names == ["chair", "couch", "tv", "lamp"]
    assert ids.tolist() == [1, 2, 3, 0]
    assert matched == {"Sofa": "couch", "monitor": "tv", "lamp": None, "chair": "chair"}


def test_a_map_in_another_vocabulary_aligns():
    rng = np.random.default_rng(4)
    room = synthetic_map(rng, 40, num_classes=4)
    room.class_names = ["couch", "tv", "chair", "table"]
    x = room.ellipsoids.centers[:, 0]
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    query = moved(room.subset(np.flatnonzero(x < 3.2)), truth, rng)
    order = [2, 3, 0, 1]  # the query vocabulary lists other names in another order
    query.class_names = ["chair", "dining table", "sofa", "monitor"]
    query.class_ids = np.array([order.index(c) for c in query.class_ids])
    query.text_embeddings, query.encoder = None, "none"
    alignment = align_maps(query, room.subset(np.flatnonzero(x > 1.8)), CONFIG)
    assert errors(alignment.candidates[0].pose, truth, query)[0] < 0.05
    assert alignment.vocabulary == {"chair": "chair", "dining table": "table", "sofa": "couch", "monitor": "tv"}
    assert any("alpha = 0" in note for note in alignment.notes)


def test_g2o_edge_holds_the_transform_and_a_positive_information_matrix():
    rng = np.random.default_rng(0)
    room = synthetic_map(rng, 40)
    truth = Pose(random_rotation(rng), np.array([1.0, 2.0, 3.0]))
    query = moved(room, truth, rng)
    best = align_maps(query, room, CONFIG).candidates[0]
    tokens = g2o_edge(best, query).split()
    assert tokens[:3] == ["EDGE_SE3:QUAT", "0", "1"] and len(tokens) == 3 + 7 + 21
    values = np.array(tokens[3:], float)
    np.testing.assert_allclose(values[:3], best.pose.translation, atol=1e-6)
    np.testing.assert_allclose(Rotation.from_quat(values[3:7]).as_matrix(), best.pose.rotation, atol=1e-6)
    information = np.zeros((6, 6))
    information[np.triu_indices(6)] = values[7:]
    assert np.all(np.diag(information) > 0) and np.count_nonzero(information - np.diag(np.diag(information))) == 0


def test_align_command_writes_json_g2o_and_a_recording(tmp_path):
    import json

    from typer.testing import CliRunner

    from clipclique.io.mapfile import save_map
    from clipclique.localization.cli import app

    rng = np.random.default_rng(2)
    room = synthetic_map(rng, 40)
    x = room.ellipsoids.centers[:, 0]
    truth = Pose(random_rotation(rng), np.array([0.5, -1.0, 2.0]))
    save_map(moved(room.subset(np.flatnonzero(x < 3.2)), truth, rng, noise=0.0), tmp_path / "a.map.npz")
    save_map(room.subset(np.flatnonzero(x > 1.8)), tmp_path / "b.map.npz")
    result = CliRunner().invoke(app, ["align", str(tmp_path / "a.map.npz"), str(tmp_path / "b.map.npz"),
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    document = json.loads((tmp_path / "out" / "alignment.json").read_text())
    np.testing.assert_allclose(document["candidates"][0]["matrix"], truth.matrix(), atol=1e-9)
    assert document["ambiguous"] is False and document["candidates"][0]["confidence"] > 0.5
    assert 0.1 < document["candidates"][0]["rotation_sigma_deg"] < 0.2  # noise-free: the 1 cm floor on the rms
    edge = (tmp_path / "out" / "alignment.g2o").read_text().splitlines()
    assert edge[0].startswith("# vertex 0: ") and edge[1].split()[3:6] == [f"{v:.9g}" for v in truth.translation]
    assert (tmp_path / "out" / "recording.rrd").stat().st_size > 1000


def test_a_map_too_small_to_align_says_why(tmp_path):
    from clipclique.localization.align import AlignSettings, alignment_document

    rng = np.random.default_rng(0)
    room = synthetic_map(rng, 40)
    query = room.subset(np.arange(2))
    alignment = align_maps(query, room, CONFIG)
    assert alignment.candidates == [] and not alignment.ambiguous
    document = alignment_document(AlignSettings(tmp_path / "a", tmp_path / "b"), alignment, query, room)
    assert document["failure"] == "fewer than 3 observations (2)" and document["failure_kind"] == "few_observations"
    assert document["g2o"] is None


def test_few_correspondence_wrong_answers_between_two_detectors_maps_are_not_confident():
    """Maps of one room by two simulated detectors (clipclique.sim.mappairs): before the evidence, 3 to 6
    correspondences of a sparse overlap gave wrong transforms confidence 0.95-1.0 (seeds 39, 58, 71, 117); before
    the rotation's standard error, seed 58 (6 correspondences, 18 degrees off) had 0.83."""
    from clipclique.sim.mappairs import detector_pair

    wrong, right = [], []
    for seed in range(120):
        query, map, truth = detector_pair(np.random.default_rng(20_000 + seed))
        alignment = align_maps(query, map, CONFIG)
        if not alignment.candidates or alignment.ambiguous:
            continue
        best = alignment.candidates[0]
        translation, rotation = errors(best.pose, truth, query)
        (right if translation < 0.3 and rotation < 5 else wrong).append((seed, len(best.correspondences),
                                                                         best.confidence))
    confident = [case for case in wrong if case[2] >= 0.5]
    assert len(wrong) >= 10 and confident == []
    assert sum(confidence >= 0.5 for _, _, confidence in right) >= 0.85 * len(right) >= 12  # 15 of 17


def test_a_rotation_the_correspondences_leave_loose_is_never_confident():
    """A cross of four points at 1 m in a plane: the least constrained turn is about an in-plane axis (moment 2 m^2),
    so rms 0.1 m gives 0.1 / sqrt(3 * 2) rad; points along a line leave the turn about it free."""
    cross = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]])
    assert rotation_sigma(cross, 0.1) == pytest.approx(math.degrees(0.1 / math.sqrt(6)), rel=1e-12)  # 2.34 degrees
    line = np.outer(np.arange(5.0), [1, 0, 0])  # the moment about the line is 0, floored at 1 cm^2
    assert rotation_sigma(line, 0.01) == pytest.approx(math.degrees(0.01 / math.sqrt(3e-4)), rel=1e-12)  # 33 degrees
    features = np.array([math.log(12), 0.5, 0.8, 1.0, 0.0, 0.5, math.log(2.4)])
    assert supported(0.9, features) == 0.9
    features[-1] = math.log(2.6)  # twice 2.6 degrees is past the 5 degrees a right answer may be off
    assert supported(0.9, features) == 0.4


def test_an_lvis_map_aligns_with_a_coco_map_of_the_same_room_as_the_same_vocabulary_does():
    """MSG-Loc's LVIS maps against COCO ones: classes meet through LVIS_TO_COCO (before: 7 of 8 classes unmatched)."""
    import dataclasses

    coco = ["keyboard", "mouse", "cup", "tv", "couch", "laptop", "book", "chair"]
    lvis = ["computer keyboard", "mouse (computer equipment)", "mug", "television set", "sofa", "laptop computer",
            "book", "armchair"]
    rng = np.random.default_rng(11)
    room = dataclasses.replace(synthetic_map(rng, 40), class_names=coco)
    truth = Pose(random_rotation(rng), rng.uniform(-5, 5, 3))
    x = room.ellipsoids.centers[:, 0]
    query = moved(room.subset(np.flatnonzero(x < 3.2)), truth, rng)
    same = align_maps(query, room.subset(np.flatnonzero(x > 1.8)), CONFIG)
    other = align_maps(dataclasses.replace(query, class_names=lvis), room.subset(np.flatnonzero(x > 1.8)), CONFIG)
    assert other.vocabulary == dict(zip(lvis, coco))
    assert len(other.candidates[0].correspondences) == len(same.candidates[0].correspondences) >= 6
    np.testing.assert_allclose(other.candidates[0].pose.matrix(), same.candidates[0].pose.matrix(), atol=1e-12)


def test_a_detector_pair_in_lvis_names_is_the_coco_pair_renamed():
    """The second vocabulary of the generated pairs: the same seed gives the same maps, the query map's classes in
    LVIS names that the alignment matches back to the map's COCO ones."""
    from clipclique.sim.mappairs import COCO, LVIS, detector_pair

    coco_query, coco_map, coco_truth = detector_pair(np.random.default_rng(20_003), "coco")
    query, map, truth = detector_pair(np.random.default_rng(20_003), "lvis")
    np.testing.assert_array_equal(query.ellipsoids.centers, coco_query.ellipsoids.centers)
    np.testing.assert_array_equal(query.class_ids, coco_query.class_ids)
    assert map.class_names == coco_map.class_names == COCO[:len(map.class_names)] and query.class_names == LVIS
    assert query.descriptions[0] == LVIS[query.class_ids[0]]
    alignment = align_maps(query, map, CONFIG)
    assert alignment.vocabulary == {lvis: coco if coco in map.class_names else None for lvis, coco in zip(LVIS, COCO)}
    with pytest.raises(ValueError, match="vocabulary 'wordnet' is not one of generic, coco, lvis"):
        detector_pair(np.random.default_rng(0), "wordnet")


def test_align_three_maps_checks_that_the_cycle_closes_and_names_the_weakest_link(tmp_path):
    from typer.testing import CliRunner

    from clipclique.io.mapfile import save_map
    from clipclique.localization.cli import app
    from clipclique.localization.cycle import cycle

    rng = np.random.default_rng(5)
    room = synthetic_map(rng, 45)
    x = room.ellipsoids.centers[:, 0]
    parts = [np.flatnonzero(x < 3.5), np.flatnonzero((x > 0.8) & (x < 4.3)), np.flatnonzero(x > 1.5)]
    for name, part in zip("abc", parts):
        save_map(moved(room.subset(part), Pose(random_rotation(rng), rng.uniform(-5, 5, 3)), rng),
                 tmp_path / f"{name}.map.npz")
    save_map(synthetic_map(rng, 45), tmp_path / "other.map.npz")
    args = ["align", *(str(tmp_path / f"{name}.map.npz") for name in "ab"), "--out", str(tmp_path / "out"), "--no-rrd"]
    closed = CliRunner().invoke(app, [*args, str(tmp_path / "c.map.npz")])
    assert closed.exit_code == 0, closed.output
    assert "cycle closes: " in closed.output and (tmp_path / "out" / "c_into_a" / "alignment.json").is_file()
    broken = CliRunner().invoke(app, [*args, str(tmp_path / "other.map.npz")])
    assert broken.exit_code == 0 and "cycle does not close (limits 2 deg, 0.05 m)" in broken.output, broken.output
    assert "weakest link " in broken.output and "other.map.npz" in broken.output.split("weakest link ")[1]
    link = {"query_map": "a", "map": "b", "candidates": [{"matrix": np.eye(4).tolist(), "confidence": 0.9}]}
    turned = Pose(Rotation.from_euler("z", 3, degrees=True).as_matrix(), np.zeros(3)).matrix().tolist()
    check = cycle([link, link | {"query_map": "b", "map": "c"},
                   {"query_map": "c", "map": "a", "candidates": [{"matrix": turned, "confidence": 0.4}]}], np.eye(3))
    assert not check.closes and check.rotation_deg == pytest.approx(3.0) and check.weakest == "c into a"
