"""Label sets (`--labels`): names files as MSG-Loc ships them, the bundled COCO and LVIS lists, LVIS maps and
detection files read through them, and the LVIS-to-COCO table that lets the two vocabularies meet."""

from __future__ import annotations

import json

import pytest

from clipclique.interop.errors import InteropError
from clipclique.interop.labels import (
    COCO,
    LVIS_TO_COCO,
    MAX_LABELS,
    class_lookup,
    duplicate_note,
    label_set,
    read_label_file,
)
from clipclique.interop.maps import read_map
from clipclique.perception.yolo import COCO_NAMES
from tests.unit.test_interop_detections import CLASSES, detector, frame
from tests.unit.test_interop_maps import msgloc_node


def test_bundled_sets_hold_the_published_ids():
    lvis = label_set("lvis")
    assert (len(lvis.names) == 1203 and lvis.names[704] == "mouse (computer equipment)"
            and lvis.names[0] == "aerosol can")
    assert label_set(None) is COCO and label_set("coco").names == tuple(COCO_NAMES) and COCO.names[41] == "cup"
    assert lvis.duplicates == {}
    assert set(LVIS_TO_COCO) <= set(lvis.names) and set(LVIS_TO_COCO.values()) <= set(COCO_NAMES)


def test_names_file_final_newline_optional_crlf_accepted(tmp_path):
    for text in ("cup\nmug\nbook", "cup\nmug\nbook\n", "cup\r\nmug\r\nbook\r\n"):
        (tmp_path / "l.txt").write_bytes(text.encode())
        assert read_label_file(tmp_path / "l.txt").names == ("cup", "mug", "book")


@pytest.mark.parametrize("text, problem", [
    ("cup\n\nbook\n", r"l.txt, line 2: a blank line; every line names the class of id 1"),
    ("", "an empty label file"),
    ("cup\nbo\x1bok\n", "line 2 'bo.x1bok' holds a control character"),
    ("x\n" * (MAX_LABELS + 1), "10001 lines; a label file holds at most 10,000"),
])
def test_hostile_names_file_refused_naming_the_line(tmp_path, text, problem):
    (tmp_path / "l.txt").write_text(text)
    with pytest.raises(InteropError, match=problem.replace("(", r"\(")):
        read_label_file(tmp_path / "l.txt")


def test_two_ids_with_one_name_are_accepted_with_a_note(tmp_path):
    (tmp_path / "l.txt").write_text("cup\nbook\ncup\n")
    labels = read_label_file(tmp_path / "l.txt")
    assert labels.duplicates == {"cup": [0, 2]} and labels.name(2, "here") == "cup"
    assert duplicate_note(labels) == [f"{tmp_path / 'l.txt'}: 1 names given to several ids (first 'cup': ids 0, 2); "
                                      "those ids are one class"]


def test_lvis_msgloc_map_needs_labels_lvis(tmp_path):
    """MSG-Loc's desk_*_lvis_map.json: ids 704 (mouse) and 295 (computer keyboard) are not COCO-80 ids."""
    path = tmp_path / "desk_yolo_lvis_map.json"
    node = msgloc_node(baseline_label={"704.0": [0.7, [1, 2, 3]], "295.0": [0.3, [1, 2, 3]]})
    path.write_text(json.dumps({"nodes": [node]}))
    with pytest.raises(InteropError,
                       match=r"category id 704 is not a coco class id \(0..79\); an LVIS file\? pass --labels lvis"):
        read_map(path)
    imported = read_map(path, labels=label_set("lvis"))
    assert imported.classes == ["mouse (computer equipment)"]
    assert imported.distributions[0] == pytest.approx({"mouse (computer equipment)": 0.7, "computer keyboard": 0.3})


def test_vocabularies_meet_through_the_lvis_to_coco_table():
    lvis_map = ["computer keyboard", "mouse (computer equipment)", "mug", "book", "television set"]
    lookup = class_lookup(lvis_map)  # COCO detections against an LVIS map
    assert [lookup[name] for name in ("keyboard", "mouse", "cup", "book", "tv")] == [0, 1, 2, 3, 4]
    assert lookup["computer keyboard"] == 0 and "person" not in lookup
    coco_map = ["keyboard", "mouse", "cup", "monitor"]
    lookup = class_lookup(coco_map)  # LVIS detections against a COCO map (monitor: COCO's tv, as for YOLO)
    assert ([lookup[name] for name in ("computer keyboard", "mouse (computer equipment)", "mug", "television set")]
            == [0, 1, 2, 3])
    assert "aerosol can" not in lookup


def test_lvis_detection_file_against_a_coco_map(tmp_path):
    path = tmp_path / "detections.json"
    path.write_text(json.dumps([{"file_name": "rgb/1311868164.363181.png", "detections": [
        {"category_id": 343, "detection_score": 0.9, "bbox": [58, 38, 102, 82]},  # LVIS 'cup' at the cup
        {"category_id": 0, "detection_score": 0.8, "bbox": [0, 0, 20, 20]}]}]))  # aerosol can: not in the map
    assert label_set("lvis").names[343] == "cup"
    found = detector(path, labels=label_set("lvis")).detect(frame())
    assert found.class_ids.tolist() == [CLASSES.index("cup")] and found.scores.tolist() == [0.9]
    with pytest.raises(InteropError, match="category id 343 is not a coco class id"):
        detector(path)  # read as COCO-80 ids


def lvis_room(labels: str | None = "lvis"):
    """Six landmarks in LVIS names, two COCO cups split over `mug` and `teacup`, with class distributions."""
    import numpy as np

    from clipclique.sim.synthetic import synthetic_map

    room = synthetic_map(np.random.default_rng(3), 6)
    names = ["book", "computer keyboard", "cup", "mug", "teacup", "aerosol can"]
    distributions = np.eye(6)[[0, 1, 2, 3, 4, 5]] * 0.5 + np.eye(6)[[3, 1, 3, 2, 3, 5]] * 0.5
    source = {"kind": "import"} | ({"labels": labels} if labels else {})
    return room.__class__(room.ellipsoids, np.arange(6), names, list(names), room.instance_ids, None, "none",
                          {"source": source}, distributions)


def test_an_lvis_map_met_by_coco_detections_names_its_classes_by_their_coco_class():
    """Before: a COCO `cup` detection reached the map's `cup` alone; its `mug` and `teacup` had no counterpart."""
    import numpy as np

    from clipclique.interop.labels import met_by

    room = lvis_room()
    met, note = met_by(room, COCO)
    assert met.class_names == ["book", "keyboard", "cup", "aerosol can"]
    assert met.class_ids.tolist() == [0, 1, 2, 2, 2, 3]
    lookup = class_lookup(met.class_names)
    assert {i for i, c in enumerate(met.class_ids) if c == lookup["cup"]} == {2, 3, 4}
    np.testing.assert_allclose(met.class_distributions, [[0.5, 0, 0.5, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                         [0, 0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert note == ["LVIS map met by COCO detections: 3 of its 6 classes named by their COCO class (computer keyboard "
                    "-> keyboard, mug -> cup, teacup -> cup), 4 classes in all"]
    assert room.class_names[3] == "mug" and room.class_ids.tolist() == list(range(6))  # the map read is untouched


def test_maps_and_detections_of_one_vocabulary_are_met_as_they_are():
    from clipclique.interop.labels import met_by

    for room, labels in ((lvis_room(), label_set("lvis")), (lvis_room(labels=None), COCO),
                         (lvis_room(labels="coco"), COCO)):
        met, note = met_by(room, labels)
        assert met is room and note == []


def test_an_import_records_its_label_set_and_a_coco_file_run_meets_the_lvis_map(tmp_path):
    """As `clipclique-loc run` prepares it: the map met first, the file's detector made for the met classes, so a
    COCO `cup` detection names the class of both the map's `cup` and its `mug` (before: only `cup`)."""
    from clipclique.interop.commands import AlignmentRequest, import_map
    from clipclique.interop.detections import FileDetector
    from clipclique.localization.run import met_by_detections

    path = tmp_path / "desk_yolo_lvis_map.json"
    nodes = [msgloc_node(node_id=i, baseline_label={category: [1.0, [1, 2, 3]]})
             for i, category in enumerate(("707.0", "343.0", "704.0"))]  # mug, cup, mouse (computer equipment)
    path.write_text(json.dumps({"nodes": nodes}))
    map = import_map(path, None, None, AlignmentRequest(), None, label_set("lvis")).map
    assert map.provenance["source"]["labels"] == "lvis" and map.class_names == [
        "cup", "mouse (computer equipment)", "mug"]
    detections = tmp_path / "detections.json"
    detections.write_text(json.dumps([{"file_name": "rgb/1311868164.363181.png", "detections": [
        {"category_id": 41, "detection_score": 0.9, "bbox": [58, 38, 102, 82]}]}]))  # COCO 'cup' at the cup
    notes: list[str] = []
    met = met_by_detections(map, f"file:{detections}", None, notes)
    assert met.class_names == ["cup", "mouse"] and met.class_ids.tolist() == [0, 0, 1]
    assert notes and notes[0].startswith("LVIS map met by COCO detections: 2 of its 3 classes")
    found = FileDetector.load(f"file:{detections}", met.class_names).detect(frame())
    assert found.class_ids.tolist() == [0] == [met.class_ids[0]] == [met.class_ids[1]]
    as_read = FileDetector.load(f"file:{detections}", map.class_names).detect(frame())
    assert as_read.class_ids.tolist() == [0] and map.class_ids.tolist() == [2, 0, 1]  # the mug: no counterpart
    lvis_notes: list[str] = []
    assert met_by_detections(map, f"file:{detections}", "lvis", lvis_notes) is map and lvis_notes == []
    assert met_by_detections(map, "simulated-yolo", None, lvis_notes) is map


class PromptEncoder:
    """A stand-in for real CLIP's text side: fixed unit vectors per class name, near where the names mean one
    thing (`coffee mug` and `cup`), between two classes where a name could mean either."""

    name, simulated = "prompt-clip", False
    VECTORS = {"book": [1, 0, 0, 0], "cup": [0, 1, 0, 0], "monitor": [0, 0, 1, 0],
               "coffee mug": [0.1, 0.98, 0.05, 0.1], "screen or tablet": [0.6, 0, 0.6, 0.5],
               "spaceship": [0, 0, 0, 1]}

    def encode_text(self, texts):
        import numpy as np

        rows = np.array([self.VECTORS[text.removeprefix("a photo of a ")] for text in texts], np.float32)
        return rows / np.linalg.norm(rows, axis=1, keepdims=True)


def test_names_no_table_holds_meet_by_text_embeddings_when_one_class_stands_out():
    from clipclique.interop.labels import text_matches

    found = text_matches(["coffee mug", "screen or tablet", "spaceship"], CLASSES, PromptEncoder())
    assert list(found) == ["coffee mug"] and found["coffee mug"][0] == CLASSES.index("cup")
    assert found["coffee mug"][1] > 0.97
    simulated = PromptEncoder()
    simulated.simulated = True
    assert text_matches(["coffee mug"], CLASSES, simulated) == {}


def test_a_grounding_dino_style_file_meets_the_map_by_text_where_real_clip_is_loaded(tmp_path):
    """Before: `coffee mug` detections were dropped, no table holding the name."""
    (tmp_path / "prompts.txt").write_text("coffee mug\nspaceship\n")
    path = tmp_path / "detections.json"
    path.write_text(json.dumps([{"file_name": "rgb/1311868164.363181.png", "detections": [
        {"category_id": 0, "detection_score": 0.9, "bbox": [58, 38, 102, 82]},
        {"category_id": 1, "detection_score": 0.8, "bbox": [0, 0, 20, 20]}]}]))
    labels = read_label_file(tmp_path / "prompts.txt")
    assert detector(path, labels=labels).detect(frame()).class_ids.tolist() == []
    found = detector(path, labels=labels)
    assert found.meet_by_text(None) == []
    note = found.meet_by_text(PromptEncoder())
    assert note == ["detections.json: 1 classes met by their text embeddings (prompt-clip): 'coffee mug' as 'cup' "
                    "(0.99); 1 without a counterpart (first 'spaceship')"]
    assert found.detect(frame()).class_ids.tolist() == [CLASSES.index("cup")]
