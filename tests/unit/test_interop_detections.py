"""Detection files: the OA-SLAM / VOOM / GOReloc JSON (boxes), COCO results with RLE masks, the box-only
segmentation, cross-class duplicates, and the COCO file a run writes read back to the same detections."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from clipclique.interop.boxfit import BoxSegmentation, box_mask, ellipse_region
from clipclique.interop.coco import decode_rle, encode_rle, reported_classes
from clipclique.interop.detections import (
    CocoRecorder,
    FileDetector,
    frame_key,
    merged_duplicates,
    read_detections,
)
from clipclique.interop.errors import InteropError
from clipclique.perception.yolo import coco_to_vocabulary
from clipclique.types import Detections, Frame

INTRINSICS = np.array([[500.0, 0, 80], [0, 500.0, 60], [0, 0, 1]])
CLASSES = ["book", "cup", "monitor"]


def frame(name: str = "1311868164.363181", index: int = 0) -> Frame:
    """A 160x120 frame: a wall at 2 m, a 'cup' disc of 20 px radius at 1 m centred at (80, 60)."""
    depth = np.full((120, 160), 2.0, np.float32)
    v, u = np.mgrid[:120, :160]
    depth[(u - 80) ** 2 + (v - 60) ** 2 <= 400] = 1.0
    return Frame(index, 0.0, np.zeros((120, 160, 3), np.uint8), depth, INTRINSICS, None, name=name)


def detector(path, **options) -> FileDetector:
    return FileDetector.load(f"file:{path}", CLASSES, **options)


def test_frame_keys_drop_folders_and_image_extensions():
    assert frame_key("rgb/1311868164.363181.png") == frame_key("1311868164.363181.png") == "1311868164.363181"
    assert frame_key("1311868164.363181") == "1311868164.363181" and frame_key("17") == "17"


def test_detection_json_boxes_become_depth_segmented_masks(tmp_path):
    path = tmp_path / "detections.json"
    path.write_text(json.dumps([
        {"file_name": "rgb/1311868164.363181.png", "detections": [
            {"category_id": 41, "detection_score": 0.9, "bbox": [58, 38, 102, 82]},  # the cup, box a little loose
            {"category_id": 39, "detection_score": 0.5, "bbox": [59, 39, 101, 81]},  # the same cup as 'bottle'
            {"category_id": 62, "detection_score": 0.2, "bbox": [0, 0, 30, 30]}]},   # tv -> monitor, low score
        {"file_name": "3", "detections": [{"category_id": 73, "detection_score": 0.4, "bbox": [0, 0, 10, 10]}]}]))
    found = detector(path).detect(frame())
    assert found.class_ids.tolist() == [1, 2] and found.scores.tolist() == [0.9, 0.2]  # bottle not in the map
    disc = frame().depth == 1.0
    assert (found.masks[0] & ~disc).sum() == 0 and found.masks[0].sum() > 0.9 * disc.sum()  # the wall rejected
    assert detector(path, min_score=0.25).detect(frame()).class_ids.tolist() == [1]
    assert detector(path).detect(frame("other", index=3)).class_ids.tolist() == [0]  # named by frame index
    assert len(detector(path).detect(frame("unlisted", index=9))) == 0


def test_cross_class_duplicates_keep_the_best_report_only():
    boxes = np.array([[0, 0, 10, 10], [0, 0, 10, 9.5], [0, 0, 10, 9.8], [50, 50, 60, 60]], float)
    kept = merged_duplicates(boxes, np.array([1, 2, 1, 2]), np.array([0.5, 0.9, 0.7, 0.3]))
    assert kept.tolist() == [1, 3]  # the cup reports (0, 2) lose to the bottle at IoU 0.95 and 0.98
    same_class = merged_duplicates(boxes[:3], np.array([1, 1, 1]), np.array([0.5, 0.9, 0.7]))
    assert same_class.tolist() == [0, 1, 2]  # the detector's own NMS decides those


def test_voom_ellipse_is_turned_clockwise_on_screen_by_its_angle():
    upright = ellipse_region(np.zeros(4), (120, 160), np.array([80, 60, 20, 60, 0.0]))
    turned = ellipse_region(np.zeros(4), (120, 160), np.array([80, 60, 20, 60, math.pi / 2]))
    assert np.ptp(np.nonzero(upright)[0]) > 50 > np.ptp(np.nonzero(turned)[0])  # tall, then wide
    assert (turned == ellipse_region(np.zeros(4), (120, 160), np.array([80, 60, 60, 20, 0.0]))).mean() > 0.99


def test_box_mask_keeps_the_nearest_dominant_mode():
    depth = frame().depth.copy()
    depth[60:, :] = np.where(depth[60:, :] == 1.0, 1.0, 1.5)  # a table in front of the wall, behind the cup
    mask = box_mask(depth, INTRINSICS, np.array([58.0, 38, 102, 82]))
    assert set(np.unique(depth[mask])) == {1.0}


def test_box_mask_keeps_the_near_part_of_a_slanted_surface():
    """A table top seen at a slant (1.2 m at its near edge, row 89, to 1.38 m at row 30) before a wall at
    3 m: its depth mode lies mid-table, and the band reaches half its likely depth extent in front."""
    depth = np.full((120, 160), 3.0, np.float32)
    v, u = np.mgrid[:120, :160]
    top = (v >= 30) & (v < 90) & (u >= 30) & (u < 130)
    depth[top] = (1.2 + 0.003 * (89 - v))[top]
    box = np.array([30.0, 30, 130, 90])
    inside = ellipse_region(box, depth.shape) & top
    for front_share, last_row, share in ((0.5, 84, 0.96), (0.0, 72, 0.77)):  # now; 4 cm in front as before
        mask = box_mask(depth, INTRINSICS, box, params=BoxSegmentation(front_share=front_share))
        assert np.nonzero(mask.any(axis=1))[0].max() == last_row
        assert (mask & top).sum() / inside.sum() == pytest.approx(share, abs=0.005)
        assert not (mask & ~top).any()  # the wall stays out


@pytest.mark.parametrize("content, problem", [
    ({"file_name": "a.png"}, "needs 'file_name' and a 'detections' list"),
    ({"file_name": "a.png", "detections": [{"category_id": 80, "detection_score": 0.5, "bbox": [0, 0, 1, 1]}]},
     r"category id 80 is not a coco class id \(0..79\); an LVIS file\? pass --labels lvis"),
    ({"file_name": "a.png", "detections": [{"category_id": 1, "detection_score": 2, "bbox": [0, 0, 1, 1]}]},
     "detection_score 2 is not a number in"),
    ({"file_name": "a.png", "detections": [{"category_id": 1, "detection_score": 0.5, "bbox": [5, 0, 1, 1]}]},
     "is not a box with x2 > x1"),
    ({"file_name": "a.png", "detections": [{"category_id": 1, "detection_score": 0.5, "bbox": [0, 0, 1, 1],
                                            "ellipse": [1, 1, -2, 2, 0]}]}, "ellipse should be"),
])
def test_malformed_detection_json_is_one_line_naming_the_entry(tmp_path, content, problem):
    path = tmp_path / "detections.json"
    path.write_text(json.dumps([content]))
    with pytest.raises(InteropError, match=rf"detections.json, entry 0.*{problem}"):
        read_detections(path)


def test_rle_round_trip_and_corrupt_counts():
    rng = np.random.default_rng(0)
    for size in rng.integers(1, 60, (100, 2)):  # pycocotools encodes, the reader decodes on its own
        mask = rng.random(size) < rng.random()
        assert (decode_rle(encode_rle(mask), "here") == mask).all()
    for full in (np.zeros((3, 4), bool), np.ones((3, 4), bool)):
        assert (decode_rle(encode_rle(full), "here") == full).all()
    assert decode_rle({"size": [2, 2], "counts": [1, 2, 1]}, "here").T.ravel().tolist() == [False, True, True, False]
    with pytest.raises(InteropError, match=r"here: corrupt RLE counts \(runs of 2 pixels for a 2x2 mask\)"):
        decode_rle({"size": [2, 2], "counts": [1, 1]}, "here")
    with pytest.raises(InteropError, match="here: corrupt RLE counts .a character outside the RLE alphabet"):
        decode_rle({"size": [2, 2], "counts": "\u00ff"}, "here")
    with pytest.raises(InteropError, match="here: corrupt RLE counts .the text ends inside a number"):
        decode_rle({"size": [2, 2], "counts": "o"}, "here")
    with pytest.raises(InteropError, match="here: segmentation is not an RLE"):
        decode_rle({"size": [2], "counts": "x"}, "here")


def test_a_recorded_run_read_back_gives_the_same_detections(tmp_path):
    """What `--detector yolo` writes (COCO results, 91-id classes, RLE masks) reproduces its detections."""
    shot = frame()
    disc = shot.depth == 1.0
    square = np.zeros_like(disc)
    square[5:25, 100:140] = True
    original = Detections(np.array([disc, square]), np.array([[60.0, 40, 101, 81], [100, 5, 140, 25]]),
                          np.array([2, 1]), np.array([0.8312, 0.41]), np.array([-1, -1]))
    vocabulary = coco_to_vocabulary(CLASSES)
    recorder = CocoRecorder(CLASSES, reported_classes(vocabulary, CLASSES))
    assert recorder.coco_names["monitor"] == "tv"
    recorder.add(shot, original)
    recorder.write(tmp_path / "detections.json", tmp_path / "images.json")
    entries = json.loads((tmp_path / "detections.json").read_text())
    assert [e["category_id"] for e in entries] == [72, 47]  # tv, cup in COCO's 91-id scheme
    back = detector(tmp_path / "detections.json").detect(shot)
    for name in ("masks", "boxes", "class_ids", "scores"):
        np.testing.assert_array_equal(getattr(back, name), getattr(original, name))


def test_coco_results_without_their_image_list_say_how_to_give_it(tmp_path):
    path = tmp_path / "results.json"
    path.write_text(json.dumps([{"image_id": 1, "category_id": 47, "bbox": [0, 0, 1, 1], "score": 0.5}]))
    with pytest.raises(InteropError, match=r"results.json: COCO results name images by id; give the image list with"):
        read_detections(path)
    (tmp_path / "list.json").write_text(json.dumps({"images": [{"id": 2, "file_name": "x.png"}]}))
    with pytest.raises(InteropError, match=r"detection 0: image_id 1 is not in the image list"):
        read_detections(path, tmp_path / "list.json")


def voom_file(tmp_path, frames: int = 3):
    """Shaped as VOOM's diamond files: boxes with ellipses, one of them zero-width ([199.0, 278.5, 0.0, 0.0018,
    0.0])."""
    entries = [{"file_name": f"rgb/{1311868164 + i}.363181.png", "detections": [
        {"category_id": 41, "detection_score": 0.9, "bbox": [58, 38, 102, 82], "ellipse": [80, 60, 44, 44, 0.1]}]}
        for i in range(frames)]
    entries[1]["detections"].append({"category_id": 41, "detection_score": 0.4, "bbox": [199.0, 278.5, 199.0, 278.5018],
                                     "ellipse": [199.0, 278.5, 0.0, 0.0018, 0.0]})
    entries[2]["detections"].append({"category_id": 73, "detection_score": 0.4, "bbox": [10, 10, 10.5, 30]})
    path = tmp_path / "voom_detections.json"
    path.write_text(json.dumps(entries))
    return path


def test_degenerate_entries_are_skipped_with_one_warning_line(tmp_path):
    read = read_detections(voom_file(tmp_path))
    assert read.total == 5 and read.skipped == {"zero-size ellipse": 1, "box under 1 pixel": 1}
    assert [len(read.frames[f"{1311868164 + i}.363181"]) for i in range(3)] == [1, 1, 1]
    assert read.notes(tmp_path / "voom_detections.json") == [
        "voom_detections.json: 2 of 5 detections skipped: 1 zero-size ellipse, 1 box under 1 pixel "
        "(--strict-detections refuses the file instead)"]
    with pytest.raises(InteropError, match=r"entry 1, detection 1: a zero-size ellipse \(--strict-detections"):
        read_detections(voom_file(tmp_path), strict=True)


class Named:
    """A sequence as check_coverage sees it: a name and frame names."""

    def __init__(self, names: list[str]):
        self.name, self.names = "fr3_office", names

    def __len__(self) -> int:
        return len(self.names)

    def frame_name(self, i: int) -> str:
        return self.names[i]

    def trajectory(self) -> tuple[np.ndarray, list[None]]:
        return np.array([float(name) for name in self.names]), [None] * len(self.names)  # TUM names are stamps


def test_a_file_of_another_sequence_is_refused_naming_both_schemes(tmp_path):
    found = detector(voom_file(tmp_path))
    other = Named([f"1341847980.{i:06d}" for i in range(120)])
    with pytest.raises(InteropError, match=r"names frames like '1311868164.363181'; fr3_office's are like "
                                           r"'1341847980.000000' or numbers 0..119: covered 0 of 120 frames"):
        found.check_coverage(other, range(120))
    partly = Named([f"{1311868164 + i}.363181" for i in range(2)] + [f"9.{i}" for i in range(8)])
    assert found.check_coverage(partly, range(10))[-1] == ("voom_detections.json covered 2 of 10 frames; the others "
                                                           "have no detections")
    assert found.check_coverage(partly, range(0, 4)) == found.read.notes(found.path)  # 2 of 4: no coverage warning
