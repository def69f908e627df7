"""Detector back-ends on synthetic frames, and YOLO-seg through a random-weight model."""

from __future__ import annotations

import os
from collections import Counter

import numpy as np
import pytest

from clipclique.backends import make_detector
from clipclique.errors import ClipcliqueError, ModelUnavailableError
from clipclique.perception.detectors import InstanceDetector, box_masks, id_counts, instance_boxes, mask_boxes
from clipclique.perception.yolo import COCO_NAMES, YoloDetector, coco_to_vocabulary
from clipclique.sim.detectors import (
    SimulatedDetector,
    SimulatedYoloDetector,
    degrade,
    ellipse_masks,
    far_masks,
    read_lookalikes,
)
from clipclique.types import Frame, Pose

CLASSES = ["chair", "table", "lamp", "sofa"]
OBJECTS = {3: "chair", 7: "table", 9: "plant", 12: "chair"}  # 9 is not in the map's vocabulary


def make_frame(index: int = 0) -> Frame:
    instances = np.zeros((60, 80), np.int32)
    instances[5:20, 10:30] = 3
    instances[30:50, 0:40] = 7
    instances[40:45, 60:70] = 9
    instances[10:25, 50:79] = 12
    return Frame(index, float(index), np.zeros((60, 80, 3), np.uint8), np.full((60, 80), 2.0, np.float32),
                 np.array([[50.0, 0, 40], [0, 50.0, 30], [0, 0, 1]]), Pose.identity(), instances)


def test_mask_boxes_are_tight_xyxy():
    masks = np.zeros((2, 10, 12), bool)
    masks[0, 2:5, 3:7] = True
    masks[1, 9, 11] = True
    np.testing.assert_array_equal(mask_boxes(masks), [[3, 2, 7, 5], [11, 9, 12, 10]])


@pytest.mark.parametrize("largest", [40, 2**31 - 1])  # a table indexed by id, and ids too large for one
def test_instance_boxes_are_the_masks_ids_counts_and_boxes(largest):
    rng = np.random.default_rng(0)
    instances = rng.choice(np.array([-3, 0, 0, 5, 9, 17, largest], np.int32), size=(37, 53))
    instances[:, :20] = 0
    ids, counts, boxes = instance_boxes(instances)
    expected_ids, expected_counts = np.unique(instances[instances > 0], return_counts=True)
    np.testing.assert_array_equal(ids, expected_ids)
    assert ids.dtype == instances.dtype
    np.testing.assert_array_equal(counts, expected_counts)
    np.testing.assert_array_equal(boxes, mask_boxes(instances[None] == ids[:, None, None]))
    assert boxes[:, 0].min() == 20  # the empty columns are outside every box
    assert all(len(part) == 0 for part in instance_boxes(np.zeros((4, 5), np.int32))[:2])
    images = (instances, instances[:, 20:], np.abs(instances), np.zeros((0, 3), np.int32), np.abs(instances)[::2, ::3],
              np.abs(instances).astype(np.int64), np.abs(instances).astype(np.int16), np.abs(instances).ravel(),
              np.abs(instances).astype(np.uint16), np.full((2, 2), 7, np.int8), np.array([[2000, 0]], np.int32))
    for image in images:  # compiled (2-D signed), bincount (others) or numpy's unique (negative, large ids)
        got, expected = id_counts(image), np.unique(image, return_counts=True)
        assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(got, expected))


def blocky_instances(seed: int) -> np.ndarray:
    """An instance image of rectangles over one another (long runs of one id a row, as real ones have),
    with ids 0, negative and positive, one object split in two."""
    rng = np.random.default_rng(seed)
    instances = np.zeros((48, 64), np.int32)
    for object_id in rng.choice([-2, 1, 2, 3, 5, 6, 9, 11], 14):
        v0, u0 = rng.integers(0, 44), rng.integers(0, 60)
        instances[v0:v0 + rng.integers(1, 25), u0:u0 + rng.integers(1, 30)] = object_id
    instances[:, -1] = 4  # a last column of its own: a run ends at the image's edge
    instances[0, 0], instances[47, 0] = 7, 7
    return instances


@pytest.mark.parametrize("seed", range(6))
def test_instance_boxes_and_box_masks_match_numpy_on_blocky_images(seed):
    """The compiled table reads runs of one id: counts and boxes as numpy's per id over the whole image, and
    the compiled box masks equal comparing the whole image per id."""
    instances = blocky_instances(seed)
    ids, counts, boxes = instance_boxes(instances)
    expected_ids, expected_counts = np.unique(instances[instances > 0], return_counts=True)
    whole = instances[None] == expected_ids[:, None, None]
    np.testing.assert_array_equal(ids, expected_ids)
    np.testing.assert_array_equal(counts, expected_counts)
    np.testing.assert_array_equal(boxes, mask_boxes(whole))
    masks = box_masks(instances, ids, boxes)
    assert masks.dtype == bool and masks.shape == whole.shape
    np.testing.assert_array_equal(masks, whole)
    np.testing.assert_array_equal(box_masks(instances, ids[:2], boxes[:2]), whole[:2])  # a subset, as detect keeps
    assert box_masks(instances, ids[:0], boxes[:0]).shape == (0, 48, 64)


def median_beyond(depths: np.ndarray, far: float) -> bool:
    """The straightforward reference: numpy's median of the positive depths (0 without any) beyond `far`."""
    valid = depths[depths > 0]
    return (float(np.median(valid)) if len(valid) else 0.0) > far


def test_far_masks_say_what_numpys_median_says():
    """Counts decide where the median is plainly either side; between two depths either side of `far` it is
    numpy's own median of the two. Odd and even counts, depths exactly at `far`, ties, NaN, -0, inf, none."""
    far = 3.5
    f32 = np.float32
    cases = [
        [], [0.0, -0.0, np.nan], [3.5], [3.5000002], [3.4999998, 3.5000002], [3.5, 3.5000002],
        [3.4999998, 3.5000005],  # mean 3.50000015: rounds in float32 to 3.5000002 > 3.5
        [3.0, 4.0], [3.0, 4.0000005], [2.0, 3.5, 3.5, 6.0], [1.0, 3.5, 3.7, 9.0], [1.0, 2.0, 5.0],
        [np.inf, 1.0], [np.inf, 3.5], [np.inf, np.inf, 1.0], [np.nan, 4.0, -0.0, 3.0], [7.0] * 6,
        [3.5] * 4 + [3.6] * 4, [3.4] * 3 + [3.6] * 3, [3.4] * 3 + [3.6] * 4, [-1.0, 4.0],
    ]
    rng = np.random.default_rng(2)
    cases += [rng.choice([0.0, np.nan, 3.4999998, 3.5, 3.5000002, 1.0, 6.0], rng.integers(1, 30)) for _ in range(300)]
    height, width = 6, 8
    masks, boxes, depth, expected = [], [], np.zeros((height, width * len(cases)), f32), []
    for k, values in enumerate(cases):
        mask = np.zeros((height, width * len(cases)), bool)
        flat = np.zeros(height * width, bool)
        flat[:len(values)] = True
        mask[:, k * width:(k + 1) * width] = flat.reshape(height, width)
        block = np.zeros(height * width, f32)
        block[:len(values)] = np.array(values, f32)
        depth[:, k * width:(k + 1) * width] = block.reshape(height, width)
        masks.append(mask)
        boxes.append([k * width, 0, (k + 1) * width, height])
        expected.append(median_beyond(np.array(values, f32), far))
    pixels, beyond = far_masks(np.array(masks), np.array(boxes, np.int64), depth, far)
    np.testing.assert_array_equal(pixels, [len(values) for values in cases])
    np.testing.assert_array_equal(beyond, expected)
    assert 0 < sum(expected) < len(expected)
    for k in (6, 10):  # the medians between two depths either side of `far`
        assert median_beyond(np.array(cases[k], f32), far) == bool(beyond[k])
    # float64 depths and a negative `far`: no positive depth reads as 0, beyond a negative `far`
    _, negative = far_masks(np.array(masks[:3]), np.array(boxes[:3], np.int64), depth.astype(np.float64), -1.0)
    assert negative.tolist() == [True, True, True]


def test_free_pixels_are_numpys_isin_and_flatnonzero():
    detector = SimulatedYoloDetector(InstanceDetector({1: "cup", 2: "book", 4: "cup", 5: "plant", 40: "book"}, DESK))
    frame = desk_frame(0)
    rng = np.random.default_rng(1)
    frame.instances = rng.choice(np.array([-3, 0, 1, 2, 4, 5, 39, 40, 41, 10**6], np.int32), frame.instances.shape)
    frame.depth = rng.choice(np.array([0.0, -0.0, np.nan, -1.0, 0.5, np.inf], np.float32), frame.depth.shape)
    mapped, free = detector._free_pixels(frame)
    expected = np.isin(frame.instances, [1, 2, 4, 40])
    np.testing.assert_array_equal(mapped, expected)
    np.testing.assert_array_equal(free, np.flatnonzero((frame.depth > 0) & ~expected))
    assert free.dtype == np.int64 and len(free) > 0
    frame.instances = None
    mapped, free = detector._free_pixels(frame)
    assert not mapped.any() and np.array_equal(free, np.flatnonzero(frame.depth > 0))


def test_degrade_copies_the_true_boxes_into_masks_as_a_concatenation_would():
    rng = np.random.default_rng(3)
    frame = make_frame()
    frame.instances = blocky_instances(0)
    true = InstanceDetector({i: "chair" for i in range(12)}, CLASSES).detect(frame)
    spurious = ellipse_masks(np.array([[10.0, 10.0], [40.0, 60.0]]), np.array([[4.0, 6.0], [9.0, 3.0]]), 48, 64)
    for kept in (rng.random(len(true)) < 0.5, np.ones(len(true), bool), np.zeros(len(true), bool)):
        detections = degrade(true, kept, true.class_ids[kept], spurious, np.array([1, 2]), np.ones(kept.sum() + 2))
        np.testing.assert_array_equal(detections.masks, np.concatenate((true.masks[kept], spurious)))
        np.testing.assert_array_equal(detections.boxes, mask_boxes(detections.masks))
        assert detections.instance_ids.tolist() == true.instance_ids[kept].tolist() + [-1, -1]


def test_ellipse_masks_match_the_whole_frame_formula_to_the_pixel():
    """Evaluated in each blob's box only, yet the same masks as the formula over every pixel (the simulated
    detectors' output, and so every result on the generated scenes, depends on it): blobs inside, cut by
    the border, centred outside, thinner than a pixel and larger than the frame."""
    rng = np.random.default_rng(5)
    height, width = 45, 70
    centers = np.vstack([rng.uniform((0, 0), (height, width), (40, 2)), [[-3.0, 10.0], [50.0, 80.0], [22.5, 35.0],
                                                                          [10.0, 10.0], [0.0, 69.9]]])
    radii = np.vstack([rng.uniform(0.3, 30.0, (40, 2)), [[5.0, 4.0], [8.0, 12.0], [1e4, 2e4], [0.2, 9.0], [0.5, 0.5]]])
    v, u = np.mgrid[:height, :width]
    expected = (((v[None] - centers[:, 0, None, None]) / radii[:, 0, None, None]) ** 2
                + ((u[None] - centers[:, 1, None, None]) / radii[:, 1, None, None]) ** 2) <= 1.0
    np.testing.assert_array_equal(ellipse_masks(centers, radii, height, width), expected)
    excluded = np.random.default_rng(6).random((height, width)) < 0.3
    np.testing.assert_array_equal(ellipse_masks(centers, radii, height, width, excluded), expected & ~excluded)
    assert expected.any(axis=(1, 2)).sum() >= 42 and expected[-3].all()  # most blobs drawn, the huge one everywhere
    assert ellipse_masks(np.zeros((0, 2)), np.zeros((0, 2)), height, width).shape == (0, height, width)


def test_simulated_detections_box_every_mask():
    """True boxes come from the instance image, blob boxes from their masks: both are the masks' tight boxes."""
    detector = SimulatedDetector(InstanceDetector(OBJECTS, CLASSES), false_positives=3.0)
    for index in range(20):
        detections = detector.detect(make_frame(index))
        np.testing.assert_array_equal(detections.boxes, mask_boxes(detections.masks))
        assert detections.boxes.dtype == np.float64


def test_ground_truth_detections_map_ids_to_the_vocabulary():
    detections = InstanceDetector(OBJECTS, CLASSES).detect(make_frame())
    np.testing.assert_array_equal(detections.instance_ids, [3, 7, 12])  # the plant is not in the map
    np.testing.assert_array_equal(detections.class_ids, [0, 1, 0])
    assert detections.masks.shape == (3, 60, 80)
    assert detections.masks.sum(axis=(1, 2)).tolist() == [15 * 20, 20 * 40, 15 * 29]
    np.testing.assert_array_equal(detections.boxes[1], [0, 30, 40, 50])
    frame = make_frame()
    frame.instances = None
    assert len(InstanceDetector(OBJECTS, CLASSES).detect(frame)) == 0


def test_simulated_detector_degrades_truth_reproducibly():
    detector = SimulatedDetector(InstanceDetector(OBJECTS, CLASSES), miss_rate=0.3, false_positives=1.0,
                                 confusion_rate=0.2, seed=4)
    runs = [detector.detect(make_frame(i)) for i in range(200)]
    true_kept = [(d.instance_ids >= 0).sum() for d in runs]
    spurious = [(d.instance_ids < 0).sum() for d in runs]
    assert np.mean(true_kept) == pytest.approx(3 * 0.7, abs=0.2)
    assert np.mean(spurious) == pytest.approx(1.0, abs=0.2)
    truth = {3: 0, 7: 1, 12: 0}
    labels = np.concatenate([d.class_ids[d.instance_ids >= 0] for d in runs])
    expected = np.array([truth[i] for d in runs for i in d.instance_ids[d.instance_ids >= 0]])
    assert (labels != expected).mean() == pytest.approx(0.2, abs=0.06)
    again = detector.detect(make_frame(17))
    np.testing.assert_array_equal(again.masks, runs[17].masks)
    np.testing.assert_array_equal(again.class_ids, runs[17].class_ids)
    assert detector.simulated and detector.name == "simulated"
    for d in runs[:20]:
        assert d.masks.any(axis=(1, 2)).all() and d.boxes.shape == (len(d), 4)


DESK = ["cup", "bottle", "book", "cell phone", "dining table"]
DESK_OBJECTS = {1: "cup", 2: "book", 3: "dining table", 4: "cup", 5: "plant"}  # plant: not in the map


def desk_frame(index: int) -> Frame:
    """Two cups (one small), a book and a table on a 2 m deep background; the plant is unmapped."""
    instances = np.zeros((120, 160), np.int32)
    instances[20:30, 20:28] = 1  # 80 px: a small far cup
    instances[20:60, 40:70] = 2
    instances[70:115, 10:150] = 3
    instances[30:70, 100:130] = 4  # 1200 px
    instances[5:15, 140:150] = 5
    return Frame(index, float(index), np.zeros((120, 160, 3), np.uint8), np.full((120, 160), 2.0, np.float32),
                 np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]]), Pose.identity(), instances)


def test_lookalike_table_reads_as_probabilities_per_class():
    table = read_lookalikes()
    assert ("bottle", 0.5) in table["cup"] and table["book"][0] == ("cell phone", 0.4)
    for name, row in table.items():
        assert 0 < sum(p for _, p in row) < 1, name  # the true class always keeps some probability
        assert name not in {other for other, _ in row}


def test_simulated_yolo_misses_small_objects_confuses_lookalikes_and_adds_blobs_off_the_map():
    detector = make_detector("simulated-yolo", DESK_OBJECTS, DESK, seed=3)
    assert isinstance(detector, SimulatedYoloDetector) and detector.simulated and detector.name == "simulated-yolo"
    runs = [detector.detect(desk_frame(i)) for i in range(400)]
    hit = {i: np.mean([i in d.instance_ids for d in runs]) for i in (1, 2, 3, 4)}
    assert hit[1] < 0.1 < hit[4] < hit[2] < hit[3] < 0.9  # bigger masks are found more often, none always
    classes = {1: 0, 2: 2, 3: 4, 4: 0}
    pairs = Counter((classes[i], c) for d in runs for i, c in zip(d.instance_ids, d.class_ids) if i > 0)
    cups = sum(n for (true, _), n in pairs.items() if true == 0)
    assert pairs[(0, 1)] / cups == pytest.approx(0.5, abs=0.08)  # cup -> bottle, the table's probability
    assert {pair for pair in pairs if pair[0] != pair[1]} <= {(0, 1), (2, 3)}  # book -> cell phone; no flips
    # vase and bowl, cup's other look-alikes, are not in this map: those rows are ignored
    spurious = [d.masks[d.instance_ids < 0] for d in runs]
    assert sum(len(s) for s in spurious) / sum(int((d.instance_ids > 0).sum()) for d in runs) == pytest.approx(
        detector.false_positive_ratio, abs=0.08)
    mapped = np.isin(desk_frame(0).instances, [1, 2, 3, 4])
    assert all(not (s & mapped).any() for s in spurious)  # blobs lie where no mapped object is
    again = detector.detect(desk_frame(17))
    np.testing.assert_array_equal(again.masks, runs[17].masks)
    np.testing.assert_array_equal(again.class_ids, runs[17].class_ids)


def test_clutter_detector_adds_cross_class_duplicates_of_a_tenth_of_its_hits():
    plain = make_detector("simulated-yolo", DESK_OBJECTS, DESK, seed=3)
    clutter = make_detector("simulated-yolo-clutter", DESK_OBJECTS, DESK, seed=3)
    assert clutter.name == "simulated-yolo-clutter" and clutter.duplicate_rate > 0 and plain.duplicate_rate == 0
    duplicates = hits = 0
    for i in range(400):
        detections = clutter.detect(desk_frame(i))
        ids = detections.instance_ids
        for object_id in set(ids[ids > 0].tolist()):
            rows = np.flatnonzero(ids == object_id)
            hits += object_id != 3  # the table has no look-alike in this map: never duplicated
            if len(rows) == 2:  # the duplicate: same mask and box, another class (true or look-alike), a low score
                duplicates += 1
                a, b = rows
                np.testing.assert_array_equal(detections.masks[a], detections.masks[b])
                assert detections.class_ids[a] != detections.class_ids[b]
                assert {int(detections.class_ids[a]), int(detections.class_ids[b])} in ({0, 1}, {2, 3})
                assert detections.scores[b] <= 0.5
            assert len(rows) <= 2
    assert duplicates / hits == pytest.approx(clutter.duplicate_rate, abs=0.04)


def test_sparse_detector_confuses_two_in_three_where_it_detects_few_objects():
    sparse = make_detector("simulated-yolo-sparse", DESK_OBJECTS, DESK, seed=3)
    assert sparse.name == "simulated-yolo-sparse" and sparse.sparse_objects == 5 and sparse.duplicate_rate == 0
    classes = {1: 0, 2: 2, 3: 4, 4: 0}
    runs = [sparse.detect(desk_frame(i)) for i in range(600)]  # 4 mapped objects: always sparse
    pairs = Counter((classes[i], int(c)) for d in runs for i, c in zip(d.instance_ids, d.class_ids) if i > 0)
    spurious = np.mean([(d.instance_ids < 0).sum() - sparse.false_positive_ratio * (d.instance_ids > 0).sum()
                        for d in runs if (d.instance_ids > 0).any()])  # a frame that detects nothing is not sparse
    assert spurious == pytest.approx(sparse.sparse_false_positives, abs=0.2)  # 2 more false positives a frame
    for true, others in ((0, {1}), (2, {3}), (4, {0, 1, 2, 3})):  # cup -> bottle, book -> cell phone, the table
        total = sum(n for (t, _), n in pairs.items() if t == true)  # (no look-alike in the map) -> any other
        assert {c for t, c in pairs if t == true} == others | {true}
        confused = sum(n for (t, c), n in pairs.items() if t == true and c != true)
        assert confused / total == pytest.approx(2 / 3, abs=0.06)
    tables = [n for (t, c), n in pairs.items() if t == 4 and c != 4]
    assert min(tables) / max(tables) > 0.6  # the table's other classes drawn alike
    # above sparse_objects detections a frame keeps the table's probabilities (cup -> bottle 0.5), and the
    # misses are the plain detector's draws
    busy = SimulatedYoloDetector(InstanceDetector(DESK_OBJECTS, DESK), seed=3, sparse_objects=1, sparse_confusion=1.0)
    plain = SimulatedYoloDetector(InstanceDetector(DESK_OBJECTS, DESK), seed=3)
    cups = confused = 0
    for i in range(600):
        d, p = busy.detect(desk_frame(i)), plain.detect(desk_frame(i))
        hits = d.instance_ids > 0
        np.testing.assert_array_equal(d.instance_ids[hits], p.instance_ids[p.instance_ids > 0])
        if hits.sum() >= 2:
            cup = np.isin(d.instance_ids, [1, 4])
            cups += cup.sum()
            confused += (d.class_ids[cup] == 1).sum()
    assert confused / cups == pytest.approx(0.5, abs=0.08)


def test_make_detector_rejects_unknown_and_missing_yolo_weights(monkeypatch, tmp_path):
    with pytest.raises(ClipcliqueError, match="--detector"):
        make_detector("sam", OBJECTS, CLASSES)
    monkeypatch.setenv("YOLO_OFFLINE", "1")
    with pytest.raises(ModelUnavailableError, match="--yolo-weights"):
        make_detector("yolo", OBJECTS, CLASSES, yolo_weights=tmp_path / "missing-seg.pt")


def test_local_yolo_weights_keep_ultralytics_offline(monkeypatch, tmp_path):
    """A checkpoint on disk needs no network: no probe, and ultralytics starts with YOLO_OFFLINE=1
    (online, it would send usage analytics on every predict)."""
    import sys
    import types

    import clipclique.perception.yolo as detectors

    seen = {}

    class FakeYolo:
        task = "segment"
        names = {0: "chair"}

        def __init__(self, weights: str) -> None:
            seen["offline"] = os.environ.get("YOLO_OFFLINE")

    monkeypatch.delenv("YOLO_OFFLINE", raising=False)
    monkeypatch.setattr(detectors, "host_reachable", lambda host: pytest.fail(f"probed {host}"))
    monkeypatch.setitem(sys.modules, "ultralytics", types.SimpleNamespace(YOLO=FakeYolo))
    weights = tmp_path / "mine-seg.pt"
    weights.write_bytes(b"checkpoint")
    detector = YoloDetector.load(weights, CLASSES)
    assert seen["offline"] == "1" and detector.class_map.tolist() == [0]


def test_coco_classes_map_to_the_vocabulary():
    table = coco_to_vocabulary(["table", "chair", "sofa", "desk"],
                               {0: "person", 56: "chair", 57: "couch", 60: "dining table", 58: "potted plant"})
    assert table.shape == (61,)
    assert table[[0, 56, 57, 60, 58]].tolist() == [-1, 1, 2, 0, -1]
    coco = coco_to_vocabulary(["table", "chair", "sofa", "cup", "book"])  # by COCO-80 id
    assert len(COCO_NAMES) == 80 and coco.shape == (80,)
    assert coco[[0, 41, 56, 57, 60, 73]].tolist() == [-1, 3, 1, 2, 0, 4]


@pytest.mark.models
def test_yolo_random_weights_output_shapes_and_class_mapping(monkeypatch):
    monkeypatch.setenv("YOLO_OFFLINE", "1")
    ultralytics = pytest.importorskip("ultralytics")
    from ultralytics.utils import ROOT, YAML

    torch = pytest.importorskip("torch")
    torch.manual_seed(0)  # random weights: seeded, or the detections depend on what ran before
    model = ultralytics.YOLO("yolov8n-seg.yaml")  # built from its config: random weights, no download
    model.model.names = YAML.load(ROOT / "cfg/datasets/coco.yaml")["names"]
    assert tuple(model.names[i] for i in range(len(model.names))) == COCO_NAMES
    detector = YoloDetector(model, ["chair", "table", "person"], confidence=0.0, device="cpu")
    assert detector.class_map[[0, 56, 60, 2]].tolist() == [2, 0, 1, -1]
    frame = make_frame()
    frame.rgb = np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    detections = detector.detect(frame)
    assert len(detections) > 0  # confidence 0 keeps random-weight boxes of the mapped classes
    assert detections.masks.shape == (len(detections), 60, 80) and detections.masks.dtype == bool
    assert detections.boxes.shape == (len(detections), 4)
    assert set(detections.class_ids.tolist()) <= {0, 1, 2}
    assert (detections.instance_ids == -1).all()


def test_instance_table_runs_of_every_length_about_its_eight_pixel_steps():
    """Runs of 1 to 26 pixels (below, at and past multiples of eight), ending at the image's edge or not, rows of
    widths 1 to 29: the counts and boxes numpy gives per id."""
    for width in range(1, 30):
        rows = []
        for length in range(1, 27):
            row = np.zeros(width, np.int32)
            row[: min(length, width)] = length % 5 + 1  # a run from the left edge
            rows.append(row)
            row = np.full(width, 9, np.int32)
            row[width - min(length, width):] = length % 3 + 1  # a run to the right edge
            rows.append(row)
        instances = np.array(rows)
        ids, counts, boxes = instance_boxes(instances)
        expected_ids, expected_counts = np.unique(instances[instances > 0], return_counts=True)
        np.testing.assert_array_equal(ids, expected_ids)
        np.testing.assert_array_equal(counts, expected_counts)
        np.testing.assert_array_equal(boxes, mask_boxes(instances[None] == expected_ids[:, None, None]))
