"""Bad data is refused or handled correctly, never answered wrongly (issue 14): one test per case."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from clipclique.config import make_config
from clipclique.datasets import open_sequence
from clipclique.errors import DatasetError, MapFileError
from clipclique.io.mapfile import validate_map
from clipclique.io.outputs import MAP_DIR
from clipclique.localization.cli import app as loc_app
from clipclique.localization.run import RunSettings
from clipclique.mapping.cli import app as map_app
from clipclique.outcomes import FailureKind
from clipclique.perception.depth import backproject
from clipclique.pipeline import index_map, localize
from clipclique.pose.distance import rotation_angle
from clipclique.pose.fit import conditioning
from clipclique.types import Ellipsoids, Map, Observations, Pose

RUNNER = CliRunner()


# ---- nearly collinear correspondences --------------------------------------------------------------

def _scene(centers: np.ndarray, noise: float, seed: int = 0) -> tuple[Map, Observations, Pose]:
    """A map of one object per class at `centers` and a frame seeing all of them, centres noisy."""
    rng = np.random.default_rng(seed)
    n = len(centers)
    rotations = np.repeat(np.eye(3)[None], n, axis=0)
    map = Map(Ellipsoids(centers, np.full((n, 3), 0.2), rotations), np.arange(n), [f"class{i}" for i in range(n)],
              [f"a class{i}" for i in range(n)], np.arange(n) + 1)
    camera = Pose(Rotation.from_euler("xyz", [10, -30, 80], degrees=True).as_matrix(), np.array([0.5, -2.0, 1.2]))
    seen = map.ellipsoids.transformed(camera.inverse())
    seen.centers = seen.centers + noise * rng.standard_normal(seen.centers.shape)
    observations = Observations(seen, np.arange(n), None, np.arange(n) + 1, np.arange(n))
    return map, observations, camera


def _localize(map: Map, observations: Observations, *overrides: str):
    config = make_config("clipclique", overrides=list(overrides))
    return localize(observations, index_map(map, config), config)


def _error_deg(pose: Pose, camera: Pose) -> float:
    return float(np.degrees(rotation_angle(pose.rotation.T @ camera.rotation)))


ROW = np.column_stack([np.linspace(0.0, 2.4, 5), [0.03, -0.03, 0, 0.03, -0.03], [0, 0.02, -0.02, -0.02, 0.02]])


def test_a_row_of_objects_gives_no_pose_rather_than_a_confident_wrong_one():
    assert conditioning(ROW) < 0.05  # the layout: a row of 5 objects, a few cm off the line
    map, observations, camera = _scene(ROW, noise=0.05)
    result = _localize(map, observations)
    assert result.hypotheses == [] and result.num_cliques == 1  # the one clique, all 5 correct, is refused
    assert result.failure.kind is FailureKind.DEGENERATE
    assert result.failure.message == "no correspondence set determines a pose (each is collinear or poorly conditioned)"
    accepted = _localize(map, observations, "pose.min_conditioning=0")  # what the issue saw: a pose far off
    assert _error_deg(accepted.hypotheses[0].pose, camera) > 20


def test_the_same_objects_spread_in_3d_give_an_accurate_pose_with_its_conditioning():
    # neighbours stay within d_adj
    spread = ROW + np.array([[0, 0, 0], [0, 0.3, 0], [0, 0, 0.3], [0, 0.3, 0.2], [0, 0, 0.3]])
    map, observations, camera = _scene(spread, noise=0.01)
    result = _localize(map, observations)
    best = result.hypotheses[0]
    assert _error_deg(best.pose, camera) < 2.0  # 1.1 deg: 1 cm of centre noise over ~0.3 m of spread
    assert np.linalg.norm(best.pose.translation - camera.translation) < 0.05
    assert (best.conditioning == pytest.approx(min(conditioning(observations.ellipsoids.centers), conditioning(spread)),
                                               rel=0.05))
    assert 0.15 < best.conditioning < 1.0


def test_conditioning_is_zero_for_a_line_and_one_for_an_even_spread():
    assert conditioning(np.outer(np.arange(5.0), [1, 2, 3])) == pytest.approx(0.0, abs=1e-7)
    assert conditioning(np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)) == pytest.approx(1.0)
    # x deviations -2, 2, 0 (variance 8/3), y deviations -0.4/3, -0.4/3, 0.8/3 (variance 0.32/9), uncorrelated
    assert conditioning(np.array([[0, 0, 0], [4, 0, 0], [2, 0.4, 0]], float)) == pytest.approx(0.2 / np.sqrt(3))


# ---- the map -------------------------------------------------------------------------------------------

def test_a_map_rotation_with_determinant_minus_one_is_refused():
    map, _, _ = _scene(np.eye(3) * 2, noise=0.0)
    map.ellipsoids.rotations[1] = np.diag([1.0, 1.0, -1.0])
    with pytest.raises(MapFileError, match=r"m\.npz: ellipsoid rotation 1 is a reflection \(determinant -1\)"):
        validate_map(map, "m.npz")


# ---- ScanNet frames -----------------------------------------------------------------------------------

def test_8_bit_depth_is_refused_naming_the_file(tmp_path, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    Image.fromarray(np.full((480, 640), 150, np.uint8)).save(folder / "depth" / "2.png")
    with pytest.raises(DatasetError, match=r"depth/2\.png: 8-bit depth image; depth must be 16-bit"):
        open_sequence(folder.name, tmp_path)[1]


def test_depth_at_half_size_gets_intrinsics_rescaled_so_points_land_where_they_are(tmp_path, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    full = open_sequence(folder.name, tmp_path)[0]
    # intrinsic_depth.txt stays 640 x 480
    Image.fromarray(np.full((240, 320), 1500, np.uint16)).save(folder / "depth" / "0.png")
    half = open_sequence(folder.name, tmp_path)[0]
    np.testing.assert_allclose(half.intrinsics[:2], full.intrinsics[:2] / 2)
    assert half.instances.shape == (240, 320)
    # the same object pixels back-project to the same place (within the 2-pixel quantization of the half image)
    centroids = [backproject(f.depth, f.intrinsics, f.instances == 1).mean(axis=0) for f in (full, half)]
    np.testing.assert_allclose(centroids[1], centroids[0], atol=0.005)


@pytest.mark.parametrize("name, matrix", [
    ("scaled", np.diag([1.5, 1.5, 1.5, 1.0])),
    ("reflection", np.diag([1.0, 1.0, -1.0, 1.0])),
    ("sheared", np.eye(4) + np.eye(4, k=1) * 0.3),
])
def test_non_rigid_ground_truth_poses_are_refused_naming_the_file(tmp_path, name, matrix, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    np.savetxt(folder / "pose" / "2.txt", matrix)
    with pytest.raises(DatasetError, match=r"pose/2\.txt: not a rigid camera pose"):
        open_sequence(folder.name, tmp_path)


def test_duplicate_object_ids_are_refused_naming_the_file(tmp_path, scannet_scene):
    folder, _ = scannet_scene(tmp_path)
    path = folder / f"{folder.name}.aggregation.json"
    document = json.loads(path.read_text())
    document["segGroups"][1]["objectId"] = 0
    path.write_text(json.dumps(document))
    with pytest.raises(DatasetError, match=r"aggregation\.json: objectId 0 appears in more than one segGroup"):
        open_sequence(folder.name, tmp_path).instances()


# ---- names ---------------------------------------------------------------------------------------------

def test_a_name_that_climbs_out_of_the_data_root_is_refused(tmp_path):
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "data" / "tum" / "rgbd_dataset_x").mkdir(parents=True)
    result = RUNNER.invoke(loc_app, ["run", "rgbd_dataset_x/../../../elsewhere", "--data-root", str(tmp_path / "data")])
    assert result.exit_code == 2
    assert result.output.strip() == (
        "clipclique-loc: error: 'rgbd_dataset_x/../../../elsewhere': a TUM sequence name is one folder name under "
        "<data root>/tum/, not a path; to open a folder elsewhere, pass its path (e.g. ./rgbd_dataset_x)")


def test_the_default_map_comes_from_the_resolved_scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "seq" / "sub").mkdir(parents=True)
    settings = RunSettings("seq/sub/..")
    assert settings.resolved_map_path() == MAP_DIR / "seq.map.npz"


# ---- smaller ones --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tum(demo_data) -> Path:
    """A 4-frame TUM-format demo sequence to copy and edit."""
    return demo_data("demo_tum") / "demo" / "demo_tum"


def _edited(tum: Path, where: Path, relative: str, text: str | bytes) -> Path:
    copy = shutil.copytree(tum, where)
    target = copy / relative
    target.write_bytes(text) if isinstance(text, bytes) else target.write_text(text)
    return copy


def test_a_nul_byte_in_a_description_is_refused(tum, tmp_path):
    folder = _edited(tum, tmp_path / "seq", "annotations/objects.csv",
                     'id,class,description\n7,desk,"a white\0 desk"\n')
    with pytest.raises(DatasetError, match=r"objects\.csv, line 2: holds a NUL byte"):
        open_sequence(str(folder)).instances()


def test_an_id_of_2_to_the_70_is_refused(tum, tmp_path):
    folder = _edited(tum, tmp_path / "seq", "annotations/objects.csv", f'id,class,description\n{2**70},desk,"a desk"\n')
    with pytest.raises(DatasetError, match=r"objects\.csv, line 2: id 1180591620717411303424 outside 1\.\.65535"):
        open_sequence(str(folder)).object_classes()


def test_a_utf8_bom_in_objects_csv_is_read_as_text(tum, tmp_path):
    original = (tum / "annotations" / "objects.csv").read_text()
    folder = _edited(tum, tmp_path / "seq", "annotations/objects.csv", "\ufeff" + original)
    assert open_sequence(str(folder)).object_classes() == open_sequence(str(tum)).object_classes()
    assert len(open_sequence(str(folder)).object_classes()) > 10


def test_an_empty_rgb_txt_says_so(tum, tmp_path):
    folder = _edited(tum, tmp_path / "seq", "rgb.txt", "# color images\n# timestamp filename\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt: lists no images"):
        open_sequence(str(folder))


def test_a_folder_named_with_markup_prints_as_it_is(tum, tmp_path):
    folder = _edited(tum, tmp_path / "seq[" / "]x", "rgb.txt", "")
    result = RUNNER.invoke(map_app, ["build", str(folder), "--out", str(tmp_path / "m.map.npz")])
    assert result.exit_code == 2
    assert f"error: {tmp_path}/seq[/]x/rgb.txt: lists no images" in result.output.replace("\n", "")


def test_class_names_with_markup_print_as_they_are(tum, tmp_path):
    objects = (tum / "annotations" / "objects.csv").read_text().replace(",desk,", ",[bold]desk[/],", 1)
    folder = _edited(tum, tmp_path / "seq", "annotations/objects.csv", objects)
    result = RUNNER.invoke(map_app, ["build", str(folder), "--out", str(tmp_path / "m.map.npz"), "--encoder",
                                     "simulated"])
    assert result.exit_code == 0, result.output
    assert "[bold]desk[/]" in result.output
    assert (tmp_path / "m.map.npz").is_file() and (tmp_path / "m.map.rrd").is_file()


def test_tum_depth_at_half_size_gets_intrinsics_rescaled_too(tum, tmp_path):
    folder = shutil.copytree(tum, tmp_path / "seq")
    full = open_sequence(str(folder))[0]
    sequence = open_sequence(str(folder))
    depth_path = folder / sequence.depth_files[0]
    # full size
    (folder / "annotations" / "instances" / f"{Path(sequence.rgb_files[0]).stem}.png").unlink(missing_ok=True)
    with Image.open(depth_path) as image:
        image.resize((80, 60), Image.NEAREST).save(depth_path)
    half = open_sequence(str(folder))[0]
    assert half.depth.shape == (60, 80) and half.rgb.shape == (60, 80, 3)
    np.testing.assert_allclose(half.intrinsics[:2], full.intrinsics[:2] / 2)
