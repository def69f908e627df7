"""A user's own TUM-format recording, as they would type the commands: annotated from instance masks made
with another tool (`clipclique-map annotate`), built into a map, localized; frames left without annotations or
ground truth, and a second recording of the same place against the first one's map."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from clipclique.datasets import open_sequence
from clipclique.localization.cli import app as loc_app
from clipclique.mapping.cli import app
from clipclique.metrics import SUCCESS_THRESHOLDS_M

RUNNER = CliRunner()
NAME = "rgbd_dataset_freiburg2_desk"  # the tiny TUM sequence of tests/conftest.py (write_tum_sequence)
T0 = 1311868164.0
RGB_STAMPS = [f"{T0 + dt + 0.0013:.6f}" for dt in (0.0, 0.1, 0.2, 0.3)]  # its colour images


def own_masks(tmp_path, names: list[str], ids: tuple[int, int] = (7, 8), mode: str = "I;16") -> tuple:
    masks = tmp_path / "masks"
    masks.mkdir()
    for name in names:
        image = np.zeros((480, 640), np.uint16)
        image[200:280, 300:340], image[200:280, 340:380] = ids
        Image.fromarray(image.astype(np.uint8) if mode == "L" else image).save(masks / f"{name}.png")
    table = tmp_path / "classes.csv"
    table.write_text('id,class,description\n7,monitor,"a black monitor, wide"\n8,cup,\n9,chair,a lone chair\n')
    return masks, table


def annotate(tmp_path, masks, table):
    return RUNNER.invoke(app, ["annotate", NAME, "--masks", str(masks), "--objects", str(table),
                               "--data-root", str(tmp_path)])


def test_masks_named_by_stem_or_timestamp_become_the_sequences_annotations_and_its_map(tmp_path, monkeypatch,
                                                                                       tum_sequence):
    folder = tum_sequence(tmp_path, annotations=False, rounded=True)
    # the first frame by its file stem, the second by a rounded timestamp, 8-bit
    masks, table = own_masks(tmp_path, [RGB_STAMPS[0]], mode="L")
    Image.open(masks / f"{RGB_STAMPS[0]}.png").save(masks / f"{float(RGB_STAMPS[1]):.3f}.png")
    done = annotate(tmp_path, masks, table)
    assert done.exit_code == 0, done.output
    assert f"annotations: {folder / 'annotations'}/ (2 frames, 3 objects)" in done.output.replace("\n", "")
    assert "objects no mask shows (no landmark for them): 9" in done.output
    sequence = open_sequence(NAME, tmp_path)
    assert sequence.object_classes() == {7: "monitor", 8: "cup", 9: "chair"}
    assert [sequence[i].instances is not None for i in range(len(sequence))] == [True, True, False]
    assert np.count_nonzero(sequence[1].instances == 8) == 80 * 40
    monkeypatch.chdir(tmp_path)
    built = RUNNER.invoke(app, ["build", NAME, "--data-root", str(tmp_path), "--encoder", "none", "--no-rrd"])
    assert built.exit_code == 0, built.output
    assert "monitor" in built.output and "cup" in built.output


@pytest.mark.parametrize("names, problem", [
    (["photo_0001"], "photo_0001.png: names no colour image of"),
    (["1311868170.0"], "1311868170.0.png: names no colour image of"),  # no frame within 0.02 s
    (["nan"], "nan.png: names no colour image of"),
    ([RGB_STAMPS[0], f"{float(RGB_STAMPS[0]) + 0.001:.6f}"], "a second mask of frame"),
])
def test_a_mask_that_names_no_frame_or_a_frame_twice_is_one_line_and_writes_nothing(tmp_path, names, problem,
                                                                                    tum_sequence):
    folder = tum_sequence(tmp_path, annotations=False)
    masks, table = own_masks(tmp_path, names)
    done = annotate(tmp_path, masks, table)
    assert done.exit_code == 2 and problem in done.output.replace("\n", "") and "Traceback" not in done.output
    assert sorted(p.name for p in folder.iterdir()) == ["depth", "depth.txt", "groundtruth.txt", "rgb", "rgb.txt"]


def test_unknown_ids_wrong_sizes_and_existing_annotations_are_refused(tmp_path, tum_sequence):
    folder = tum_sequence(tmp_path, annotations=False)
    masks, table = own_masks(tmp_path, [RGB_STAMPS[0]], ids=(7, 12))
    assert "object id 12 is not in" in annotate(tmp_path, masks, table).output.replace("\n", "")
    Image.fromarray(np.zeros((240, 320), np.uint16)).save(masks / f"{RGB_STAMPS[0]}.png")
    assert ("mask is 320 x 240, the depth image of its frame 640 x 480"
            in annotate(tmp_path, masks, table).output.replace("\n", ""))
    (folder / "annotations").mkdir()
    (folder / "annotations" / "objects.csv").write_text("id,class,description\n1,chair,mine\n")
    refused = annotate(tmp_path, masks, table)
    assert (refused.exit_code == 2
            and "exists already; annotate never replaces annotations" in refused.output.replace("\n", ""))
    assert (folder / "annotations" / "objects.csv").read_text() == "id,class,description\n1,chair,mine\n"


def test_one_scene_has_one_map_whichever_name_is_typed(tmp_path, monkeypatch, tum_sequence):
    tum_sequence(tmp_path, rounded=True)
    monkeypatch.chdir(tmp_path)
    built = RUNNER.invoke(app, ["build", "fr2", "--data-root", str(tmp_path), "--encoder", "none", "--no-rrd"])
    assert built.exit_code == 0, built.output
    assert f"map: outputs/maps/{NAME}.map.npz" in built.output
    ran = RUNNER.invoke(loc_app, ["run", NAME, "--data-root", str(tmp_path), "--no-rrd", "-q"])
    assert ran.exit_code == 0, ran.output  # finds the map fr2 built
    assert sorted(p.name for p in (tmp_path / "outputs" / "maps").iterdir()) == [f"{NAME}.map.npz"]


def test_frames_without_annotations_are_left_out_and_counted_not_failed(tmp_path, monkeypatch, tum_sequence):
    """The tiny sequence annotates one of its three frames: the run scores one, and says the other two are left out."""
    tum_sequence(tmp_path, rounded=True)
    monkeypatch.chdir(tmp_path)
    assert (RUNNER.invoke(app, ["build", NAME, "--data-root", str(tmp_path), "--encoder", "none", "--no-rrd"]).exit_code
            == 0)
    ran = RUNNER.invoke(loc_app, ["run", NAME, "--data-root", str(tmp_path), "--no-rrd"])
    assert ran.exit_code == 0, ran.output
    assert (f"note: 2 of 3 frames have no annotations for the annotations detector: left out, not counted as failures "
            f"({T0 + 0.1013:.6f}, {T0 + 0.3013:.6f})") in " ".join(ran.output.split())
    document = json.loads((tmp_path / "outputs" / "loc" / NAME / "clipclique" / "results.json").read_text())
    assert document["summary"]["frames"] == 1 and document["summary"]["not_annotated"] == 2
    assert [frame["name"] for frame in document["frames"]] == [RGB_STAMPS[0]]


def test_another_recording_of_the_same_place_is_localized_with_same_place_and_refused_without(tmp_path, monkeypatch,
                                                                                              tum_sequence):
    """A second recording of the mapped place, without ground truth: --same-place localizes it against the first
    one's map, and the table shows how many frames got a pose; without it the map is refused, naming the option."""
    folder = tum_sequence(tmp_path, rounded=True)
    ids = np.zeros((480, 640), np.uint16)
    ids[200:280, 300:330], ids[200:280, 330:350], ids[200:280, 350:380] = 4, 9, 5
    (folder / "annotations" / "objects.csv").write_text("id,class,description\n4,monitor,\n9,cup,\n5,book,\n")
    for stamp in RGB_STAMPS[:2]:
        Image.fromarray(ids).save(folder / "annotations" / "instances" / f"{stamp}.png")
    second = folder.with_name(NAME + "_second")
    shutil.copytree(folder, second)
    (second / "groundtruth.txt").unlink()  # recorded without motion capture
    monkeypatch.chdir(tmp_path)
    assert (RUNNER.invoke(app, ["build", NAME, "--data-root", str(tmp_path), "--encoder", "none", "--no-rrd"]).exit_code
            == 0)
    args = ["run", second.name, "--data-root", str(tmp_path), "--map", f"outputs/maps/{NAME}.map.npz", "--no-rrd"]
    refused = RUNNER.invoke(loc_app, args)
    assert refused.exit_code == 2
    assert (f"a map of {NAME}, not of {second.name}; if {second.name} is another recording of the place {NAME} shows, "
            "pass --same-place") in " ".join(refused.output.split())
    ran = RUNNER.invoke(loc_app, [*args, "--same-place"])
    assert ran.exit_code == 0, ran.output
    text = " ".join(ran.output.split())
    assert f"note: the map is of {NAME}, another recording of this place (--same-place)" in text
    thresholds = len(SUCCESS_THRESHOLDS_M)
    row = next(line.split() for line in ran.output.splitlines() if line.startswith("CLIP-Clique (a) ")
               and len(line.split()) == 3 + thresholds + 3)  # the pose table: name, posed, thresholds, TE and RE
    assert row[2] == "100.0" and row[3:3 + thresholds] == ["-"] * thresholds  # both posed, nothing to score them by


def two_hertz(folder) -> None:
    """groundtruth.txt at 2 Hz: no colour image (0.1 s apart from T0 + 0.0013) has a pose within 0.02 s."""
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    lines += [f"{T0 - 0.05 + 0.5 * k:.4f} 1.0 2.0 3.0 0 0 0 1" for k in range(4)]
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")


def test_sparse_ground_truth_is_named_by_build_and_run(tmp_path, monkeypatch, tum_sequence):
    folder = tum_sequence(tmp_path, rounded=True)
    monkeypatch.chdir(tmp_path)
    args = ["--data-root", str(tmp_path)]
    built = RUNNER.invoke(app, ["build", NAME, "--encoder", "none", "--no-rrd", *args])  # 100 Hz: fine
    assert built.exit_code == 0, built.output
    assert "note:" not in built.output
    two_hertz(folder)
    cause = (f"3 of 3 frames have no ground-truth pose: {folder / 'groundtruth.txt'} has no pose within 0.02 s of "
             "their colour image (its poses are 0.5 s apart: record poses at 50 Hz or more, or write one per colour "
             "image with its timestamp)")
    refused = RUNNER.invoke(app, ["build", NAME, "--encoder", "none", "--no-rrd", "--out", "sparse.map.npz", *args])
    assert refused.exit_code == 2
    assert cause in " ".join(refused.output.split()), refused.output  # not only "fewer than 30 points"
    ran = RUNNER.invoke(loc_app, ["run", NAME, "--no-rrd", *args])
    assert ran.exit_code == 0, ran.output
    assert f"note: {cause}; those frames cannot be scored" in " ".join(ran.output.split())
    assert "Top-1" in ran.output  # the table still prints, its success columns `-`, with the reason above


def test_ground_truth_that_ends_before_the_images_says_so(tmp_path, tum_sequence):
    folder = tum_sequence(tmp_path, annotations=False)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    (folder / "groundtruth.txt").write_text("\n".join(lines[:22]) + "\n")  # 100 Hz, ending at T0 + 0.15
    gap = open_sequence(NAME, tmp_path).missing_poses()
    assert gap.startswith("1 of 3 frames have no ground-truth pose") and "its poses cover" in gap
    assert np.isclose(float(gap.split("the images ")[1].split(" to ")[0]), T0 + 0.0013, atol=1e-3)


def test_a_coco_annotation_file_becomes_the_sequences_annotations(tmp_path, tum_sequence):
    """`annotate --coco`: RLE and polygon masks, the object id under CVAT's attributes or at the top, images named by
    folder and file stem or by timestamp; classes from the categories, or descriptions from --objects."""
    from clipclique.interop.coco import encode_rle

    tum_sequence(tmp_path, annotations=False, rounded=True)
    monitor = np.zeros((480, 640), bool)
    monitor[200:280, 300:340] = True
    document = {
        "images": [{"id": 1, "file_name": f"rgb/{RGB_STAMPS[0]}.png", "width": 640, "height": 480},
                   {"id": 2, "file_name": f"{float(RGB_STAMPS[1]):.3f}.png", "width": 640, "height": 480}],
        "categories": [{"id": 1, "name": "monitor"}, {"id": 2, "name": "cup"}],
        "annotations": [
            {"id": 1, "image_id": 1, "category_id": 1, "attributes": {"track_id": 7},
             "segmentation": encode_rle(monitor)},
            {"id": 2, "image_id": 1, "category_id": 2, "track_id": 8,
             "segmentation": [[340, 200, 380, 200, 380, 280, 340, 280]]},  # a 40 x 80 rectangle
            {"id": 3, "image_id": 2, "category_id": 2, "track_id": 8, "segmentation": encode_rle(monitor)},
        ],
    }
    coco = tmp_path / "instances.json"
    coco.write_text(json.dumps(document))
    done = RUNNER.invoke(app, ["annotate", NAME, "--coco", str(coco), "--data-root", str(tmp_path)])
    assert done.exit_code == 0, done.output
    assert "(2 frames, 2 objects)" in done.output.replace("\n", "")
    sequence = open_sequence(NAME, tmp_path)
    assert sequence.object_classes() == {7: "monitor", 8: "cup"}
    assert np.count_nonzero(sequence[0].instances == 7) == 80 * 40
    assert 80 * 40 <= np.count_nonzero(sequence[0].instances == 8) <= 81 * 41  # the polygon, its border pixels included
    assert np.count_nonzero(sequence[1].instances == 8) == 80 * 40 and sequence[2].instances is None
    # a second time: the annotations exist and are never replaced; with --objects the table names them
    shutil.rmtree(tmp_path / "tum" / NAME / "annotations")
    table = tmp_path / "classes.csv"
    table.write_text('id,class,description\n7,monitor,"a black monitor, wide"\n8,cup,a red cup\n')
    again = RUNNER.invoke(app, ["annotate", NAME, "--coco", str(coco), "--objects", str(table), "--data-root",
                                str(tmp_path)])
    assert again.exit_code == 0, again.output
    assert "a red cup" in (tmp_path / "tum" / NAME / "annotations" / "objects.csv").read_text()
    refused = RUNNER.invoke(app, ["annotate", NAME, "--coco", str(coco), "--data-root", str(tmp_path)])
    assert refused.exit_code == 2 and "exists already" in refused.output


def test_annotate_reads_masks_or_a_coco_file_not_both(tmp_path, tum_sequence):
    tum_sequence(tmp_path, annotations=False)
    masks, table = own_masks(tmp_path, [RGB_STAMPS[0]])
    both = RUNNER.invoke(app, ["annotate", NAME, "--masks", str(masks), "--coco", str(table), "--data-root",
                               str(tmp_path)])
    assert both.exit_code == 2 and "either --masks DIR (with --objects CSV) or --coco FILE" in both.output
    alone = RUNNER.invoke(app, ["annotate", NAME, "--masks", str(masks), "--data-root", str(tmp_path)])
    assert alone.exit_code == 2 and "--masks needs --objects CSV" in alone.output
