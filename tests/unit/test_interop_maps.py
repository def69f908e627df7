"""Readers of object-SLAM maps on files written here byte by byte (docs/import_export.md), and the writers' round
trip."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipclique.interop.convert import landmarks_json, read_objects, text_map, to_map
from clipclique.interop.errors import InteropError
from clipclique.interop.maps import MapFormat, read_map
from clipclique.interop.protowire import encode_varint as varint
from clipclique.interop.quadric import decode_dual_quadric, encode_dual_quadric

ROTATION = Rotation.from_euler("xyz", [20, -35, 70], degrees=True).as_matrix()
CENTER = np.array([0.4, -1.2, 2.5])
AXES = np.array([0.3, 0.12, 0.05])


# ---- the protobuf wire format, by hand ----------------------------------------------------------

def key(number: int, wire: int) -> bytes:
    return varint(number << 3 | wire)


def length_delimited(number: int, payload: bytes) -> bytes:
    return key(number, 2) + varint(len(payload)) + payload


def uint_field(number: int, value: int) -> bytes:
    return key(number, 0) + varint(value)


def packed_uints(number: int, values: list[int]) -> bytes:
    return length_delimited(number, b"".join(varint(v) for v in values))


def unpacked_uints(number: int, values: list[int]) -> bytes:
    return b"".join(uint_field(number, v) for v in values)


def ellipsoid_message(quadric: np.ndarray, packed: bool = True) -> bytes:
    """`1: ellipsoid {1: repeated float, Q* row-major}`, packed or one fixed32 field per value."""
    values = quadric.ravel()  # row-major
    inner = (length_delimited(1, struct.pack("<16f", *values)) if packed
             else b"".join(key(1, 5) + struct.pack("<f", v) for v in values))
    return length_delimited(1, inner)


def quadric(center=CENTER, axes=AXES, rotation=ROTATION) -> np.ndarray:
    return encode_dual_quadric(np.asarray(center), np.asarray(axes), np.asarray(rotation))


def write_osmap(tmp_path, key_name: str, files: dict[str, bytes], extra: str = "") -> object:
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    yaml = tmp_path / "map_desk.yaml"
    first = next(iter(files))
    yaml.write_text(f"%YAML:1.0\n---\n{key_name}: \"{first}\"\n{extra}cameraMatrices:\n   - {{ fx: 520.9 }}\n")
    return yaml


def same_ellipsoid(ellipsoids, i, center=CENTER, axes=AXES, rotation=ROTATION, tolerance=1e-5):
    """Centre and axes equal; axis directions equal up to order and sign (an ellipsoid's symmetries)."""
    np.testing.assert_allclose(ellipsoids.centers[i], center, atol=tolerance)
    order = np.argsort(ellipsoids.axes[i])
    np.testing.assert_allclose(ellipsoids.axes[i][order], np.sort(axes), atol=tolerance)
    expected = np.asarray(rotation)[:, np.argsort(axes)]
    np.testing.assert_allclose(np.abs(np.sum(ellipsoids.rotations[i][:, order] * expected, axis=0)), 1, atol=1e-4)
    assert np.linalg.det(ellipsoids.rotations[i]) > 0


def test_varints_as_the_protobuf_documentation_writes_them():
    assert varint(1) == b"\x01" and varint(150) == b"\x96\x01" and varint(300) == b"\xac\x02"


# ---- dual quadrics -------------------------------------------------------------------------------

def test_dual_quadric_round_trip_and_scale_invariance():
    q = quadric()
    assert q[3, 3] == pytest.approx(-1)
    for scaled in (q, 7.5 * q):  # a dual quadric is defined up to scale
        center, axes, rotation = decode_dual_quadric(scaled, "here")
        np.testing.assert_allclose(center, CENTER, atol=1e-12)
        np.testing.assert_allclose(np.sort(axes), np.sort(AXES), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1)


def test_asymmetric_dual_quadric_refused_beyond_float_tolerance():
    q = quadric()
    nearly = q.copy()
    nearly[0, 1] += 1e-7  # float32 round-off: accepted
    decode_dual_quadric(nearly, "here")
    skewed = q.copy()
    skewed[0, 1] += 1e-3
    with pytest.raises(InteropError, match="here: the dual quadric is not symmetric"):
        decode_dual_quadric(skewed, "here")
    hyperboloid = np.diag([0.09, 0.01, -0.04, -1.0])  # a squared semi-axis negative
    with pytest.raises(InteropError, match="here: the dual quadric is not an ellipsoid"):
        decode_dual_quadric(hyperboloid, "here")


# ---- text maps -----------------------------------------------------------------------------------

def test_text_map_column_major_with_classes(tmp_path):
    second = quadric(center=[1.0, 2.0, 3.0])
    lines = [f"12 41 {' '.join(f'{v:.8f}' for v in quadric().T.ravel())}",
             f"13 63 {' '.join(f'{v:.8f}' for v in second.T.ravel())}"]
    path = tmp_path / "map_objects_desk.txt"
    path.write_text("\n".join(lines) + "\n")
    imported = read_map(path)
    assert imported.source == "oaslam-txt" and imported.object_ids == [12, 13] and imported.classes == ["cup", "laptop"]
    same_ellipsoid(imported.ellipsoids, 0, tolerance=1e-6)
    np.testing.assert_allclose(imported.ellipsoids.centers[1], [1, 2, 3], atol=1e-7)


@pytest.mark.parametrize("line, problem", [
    ("12 41 1 2 3", "expected '<id> <category id> <16 numbers>'"),
    ("12 95 " + " ".join(["0"] * 16), r"category id 95 is not a coco class id \(0..79\)"),
    ("12 41 " + " ".join(["x"] * 16), "not numbers"),
    ("12 41 " + " ".join(["nan"] * 16), "the dual quadric holds non-finite numbers"),
])
def test_text_map_malformed_line_is_one_line_naming_it(tmp_path, line, problem):
    path = tmp_path / "map_objects_x.txt"
    path.write_text(line + "\n")
    with pytest.raises(InteropError, match=rf"map_objects_x.txt, line 1: {problem}"):
        read_map(path)


# ---- Osmap protobuf maps -------------------------------------------------------------------------

def goreloc_object(object_id: int, categories: list[int], counts: list[int], packed: bool) -> bytes:
    repeated = packed_uints if packed else unpacked_uints
    body = ellipsoid_message(quadric(), packed) + uint_field(2, object_id) + repeated(3, categories)
    if counts:
        body += repeated(4, counts)
    return length_delimited(1, body + repeated(5, [100, 101, 102]))


@pytest.mark.parametrize("packed", [True, False])
def test_goreloc_objects_with_class_counts_packed_or_unpacked(tmp_path, packed):
    data = goreloc_object(5, [41, 39], [3, 9], packed) + goreloc_object(6, [56], [], packed)
    yaml = write_osmap(tmp_path, "objectsFile", {"map_desk.objects": data}, "nObjects: 2\n")
    (tmp_path / "keyframes_poses_desk_tum.txt").write_text("1.0 0 0 0 0 0 0 1\n")
    imported = read_map(yaml)
    assert imported.source == "goreloc" and imported.object_ids == [5, 6]
    assert imported.classes == ["bottle", "chair"]  # the most counted class
    assert imported.distributions[0] == pytest.approx({"cup": 0.25, "bottle": 0.75})
    assert imported.distributions[1] == {"chair": 1.0}  # counts missing: one count each
    assert imported.trajectory == tmp_path / "keyframes_poses_desk_tum.txt" and not imported.notes
    same_ellipsoid(imported.ellipsoids, 0)
    map = to_map(imported, str(yaml))
    assert map.class_names == ["bottle", "chair", "cup"]
    np.testing.assert_allclose(map.class_distributions, [[0.75, 0, 0.25], [0, 1, 0]])


def test_oaslam_mapobjects_take_their_class_from_the_tracks(tmp_path):
    objects = length_delimited(1, ellipsoid_message(quadric()) + uint_field(2, 3))
    box = length_delimited(8, b"".join(key(n, 5) + struct.pack("<f", v) for n, v in zip((1, 2, 3, 4), (1, 2, 30, 40))))
    tracks = length_delimited(1, uint_field(1, 3) + uint_field(2, 73) + uint_field(3, 99) + box
                              + packed_uints(9, [0, 4]) + length_delimited(10, struct.pack("<2d", 0.9, 0.8)))
    yaml = write_osmap(tmp_path, "mapobjectsFile", {"map_desk.mapobjects": objects},
                       "nMapobjects: 3\nobjecttracksFile: \"map_desk.objecttracks\"\n")
    (tmp_path / "map_desk.objecttracks").write_bytes(tracks)
    imported = read_map(yaml)
    assert imported.classes == ["book"] and imported.object_ids == [3]
    assert imported.notes == ["map_desk.yaml declares 3 objects; the object file holds 1"]


def test_voom_objects_need_classes_from_a_csv(tmp_path):
    objects = length_delimited(1, ellipsoid_message(quadric()) + uint_field(2, 9))
    yaml = write_osmap(tmp_path, "ObjectsFile", {"map_desk.Objects": objects})
    imported = read_map(yaml)
    assert imported.classes == [None] and "no classes" in imported.notes[0]
    with pytest.raises(InteropError, match=r"object 0 \(id 9\) has no class; give classes with --objects"):
        to_map(imported, str(yaml))
    csv = tmp_path / "objects.csv"
    csv.write_text('id,class,description\n9,monitor,"a grey monitor"\n')
    map = to_map(imported, str(yaml), read_objects(csv))
    assert map.class_names == ["monitor"] and map.descriptions == ["a grey monitor"] and map.class_distributions is None


@pytest.mark.parametrize("data, problem", [
    (length_delimited(1, b"\x0a\x05\x0a\x03abc"), "holds 0 numbers|should hold floats"),
    (b"\x0a\xff\x01", "truncated protobuf"),
    (b"\x0b", "wire type 3"),
    (length_delimited(1, ellipsoid_message(quadric())), "no category ids"),
])
def test_osmap_malformed_objects_refused_naming_the_file(tmp_path, data, problem):
    yaml = write_osmap(tmp_path, "objectsFile", {"map_desk.objects": data})
    with pytest.raises(InteropError, match=rf"map_desk.objects.*({problem})"):
        read_map(yaml)


def test_osmap_file_outside_the_folder_refused(tmp_path):
    yaml = tmp_path / "map_x.yaml"
    yaml.write_text('%YAML:1.0\nobjectsFile: "../etc/passwd"\n')
    with pytest.raises(InteropError, match="should be a file name beside the .yaml"):
        read_map(yaml)


# ---- MSG-Loc ---------------------------------------------------------------------------------------

def msgloc_node(node_id=8142508126285856768, radii=(-0.3, 0.12, 0.05), **extra):
    w_first = np.roll(Rotation.from_matrix(ROTATION).as_quat(), 1)
    node = {"id": node_id, "translation": CENTER.tolist(), "orientation": w_first.tolist(), "radii": list(radii),
            "neighbor_node": [], "msgloc_label": {"66.0": [0.998], "65.0": [0.956]},
            "baseline_label": {"66.0": [0.8, [1, 2, 3]], "64.0": [0.2, [3, 4, 5]]}}
    return node | extra


def test_msgloc_negative_radii_w_first_quaternion_and_distribution(tmp_path):
    path = tmp_path / "msgloc.json"
    path.write_text(json.dumps({"nodes": [msgloc_node()], "edges": []}))
    imported = read_map(path)
    assert imported.source == "msgloc" and imported.object_ids == [8142508126285856768]
    assert (imported.classes == ["keyboard"]
            and imported.distributions[0] == pytest.approx({"keyboard": 0.8, "mouse": 0.2}))
    assert imported.notes == ["1 nodes had negative radii: their absolute values taken"]
    np.testing.assert_allclose(imported.ellipsoids.axes[0], AXES)
    np.testing.assert_allclose(imported.ellipsoids.rotations[0], ROTATION, atol=1e-12)


def test_msgloc_without_baseline_label_falls_back_to_the_likelihoods(tmp_path):
    path = tmp_path / "msgloc.json"
    node = msgloc_node()
    del node["baseline_label"]
    path.write_text(json.dumps({"nodes": [node]}))
    assert read_map(path).classes == ["keyboard"]


@pytest.mark.parametrize("change, problem", [
    ({"id": -1}, "not an unsigned 64-bit integer"),
    ({"orientation": [2, 0, 0, 0]}, "not a unit quaternion"),
    ({"radii": [0, 1, 1]}, "a radius is 0"),
    ({"translation": [1, 2]}, "translation should be a list of 3 numbers"),
    ({"baseline_label": {"cup": [0.5, [1, 2, 3]]}}, "key 'cup' is not a class id"),
    ({"baseline_label": {"66.0": [1.5, [1, 2, 3]]}}, "should start with a probability"),
])
def test_msgloc_malformed_node_refused(tmp_path, change, problem):
    path = tmp_path / "msgloc.json"
    path.write_text(json.dumps({"nodes": [msgloc_node(**change)]}))
    with pytest.raises(InteropError, match=rf"msgloc.json, node 0.*{problem}"):
        read_map(path)


# ---- writers: the round trips --------------------------------------------------------------------

def demo_like_map(tmp_path):
    path = tmp_path / "msgloc.json"
    labels = ({"56.0": [1.0, [0, 0, 0]]}, {"41.0": [0.7, [0, 0, 0]], "39.0": [0.3, [0, 0, 0]]},
              {"63.0": [1.0, [0, 0, 0]]})
    nodes = [msgloc_node(node_id=i, translation=[i * 0.5, 0.1, 2.0], baseline_label=labels[i - 1]) for i in range(1, 4)]
    path.write_text(json.dumps({"nodes": nodes}))
    return to_map(read_map(path), str(path))


def test_json_round_trip_is_exact(tmp_path):
    map = demo_like_map(tmp_path)
    out = tmp_path / "landmarks.json"
    out.write_text(landmarks_json(map))
    back = to_map(read_map(out), str(out))
    for name in ("centers", "axes", "rotations"):
        np.testing.assert_array_equal(getattr(back.ellipsoids, name), getattr(map.ellipsoids, name))
    assert back.class_names == map.class_names and back.descriptions == map.descriptions
    np.testing.assert_array_equal(back.class_distributions, map.class_distributions)
    assert back.provenance["source_object_ids"] == [1, 2, 3]


def test_text_round_trip_within_a_micrometre_and_says_what_it_cannot_write(tmp_path):
    map = demo_like_map(tmp_path)
    map.class_names[map.class_ids[0]] = "office chair"  # not a COCO class
    map.class_names[map.class_ids[1]] = "mug"  # written as COCO's cup
    text, renamed, unwritable = text_map(map)
    assert unwritable == [] and renamed == {"office chair": "chair", "mug": "cup"}
    map.class_names[map.class_ids[0]] = "lamp"  # no COCO class
    text, renamed, unwritable = text_map(map)
    assert unwritable == ["lamp"] and renamed == {"mug": "cup"}
    out = tmp_path / "map_objects_x.txt"
    out.write_text(text)
    back = read_map(out, MapFormat.OASLAM_TXT)
    assert back.object_ids == [2, 3] and back.classes == ["cup", "laptop"]
    for row, source in enumerate((1, 2)):
        same_ellipsoid(back.ellipsoids, row, map.ellipsoids.centers[source], map.ellipsoids.axes[source],
                       map.ellipsoids.rotations[source], tolerance=1e-6)


# ---- what a user passes instead of the map file ---------------------------------------------------

def test_an_osmap_binary_file_says_pass_the_yaml(tmp_path):
    yaml = write_osmap(tmp_path, "objectsFile", {"map_desk.objects": b"\x0a\x03\x0a\x01\x00"})
    for format in (None, MapFormat.OSMAP):  # it said "not UTF-8 text; save it as UTF-8" with --format osmap
        with pytest.raises(InteropError, match=r"map_desk.objects: one of an Osmap map's binary files \(protobuf\); "
                                               r"pass the map_\*.yaml that names it"):
            read_map(tmp_path / "map_desk.objects", format)
    assert yaml.name == "map_desk.yaml"


def test_a_folder_holding_one_osmap_yaml_is_read_others_get_one_message(tmp_path):
    write_osmap(tmp_path, "objectsFile", {"map_desk.objects": goreloc_object(5, [41], [2], True)})
    assert read_map(tmp_path).classes == ["cup"] and read_map(tmp_path).source == "goreloc"
    (tmp_path / "map_other.yaml").write_text("%YAML:1.0\n")
    for format in (None, MapFormat.OSMAP, MapFormat.MSGLOC):
        with pytest.raises(InteropError,
                           match=r": a folder; pass a map file \(map_objects_\*.txt, an Osmap map_\*.yaml, "
                                               r"a .json\): it holds 2 .yaml files \(map_desk.yaml, map_other.yaml\)"):
            read_map(tmp_path, format)
