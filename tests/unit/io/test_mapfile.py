"""Map file: round trip, and a clear MapFileError for every way a file can be wrong."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from clipclique.errors import MapFileError
from clipclique.io.mapfile import SCHEMA_VERSION, load_map, save_map
from clipclique.sim.poses import random_rotation
from clipclique.types import Ellipsoids, Map


def make_map(n: int = 5, dim: int | None = 8) -> Map:
    rng = np.random.default_rng(3)
    embeddings = None
    if dim:
        embeddings = rng.normal(size=(n, dim)).astype(np.float32)
        embeddings /= np.linalg.norm(embeddings, axis=1, keepdims=True)
    return Map(
        ellipsoids=Ellipsoids(rng.uniform(-3, 3, (n, 3)), rng.uniform(0.05, 1.0, (n, 3)),
                              np.array([random_rotation(rng) for _ in range(n)])),
        class_ids=np.arange(n) % 2,
        class_names=["chair", "table"],
        descriptions=[f"a chair number {i}" for i in range(n)],
        instance_ids=np.arange(n) + 10,
        text_embeddings=embeddings,
        encoder="simulated-clip" if dim else "none",
        provenance={"source": {"name": "test"}, "tool": "clipclique-map"},
    )


def rewrite(path, **changes) -> None:
    """Rewrite the arrays of an .npz map file, replacing some."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    arrays.update(changes)
    np.savez(path, **arrays)


@pytest.mark.parametrize("dim", [8, None])
def test_round_trip_keeps_every_field(tmp_path, dim):
    original = make_map(dim=dim)
    path = tmp_path / "maps" / "scene.map.npz"
    save_map(original, path)
    loaded = load_map(path)
    np.testing.assert_array_equal(loaded.ellipsoids.centers, original.ellipsoids.centers)
    np.testing.assert_array_equal(loaded.ellipsoids.axes, original.ellipsoids.axes)
    np.testing.assert_array_equal(loaded.ellipsoids.rotations, original.ellipsoids.rotations)
    np.testing.assert_array_equal(loaded.class_ids, original.class_ids)
    np.testing.assert_array_equal(loaded.instance_ids, original.instance_ids)
    assert loaded.class_names == original.class_names
    assert loaded.descriptions == original.descriptions
    assert loaded.encoder == original.encoder
    assert loaded.provenance == original.provenance
    if dim:
        np.testing.assert_array_equal(loaded.text_embeddings, original.text_embeddings)
    else:
        assert loaded.text_embeddings is None
    assert [p.name for p in path.parent.iterdir()] == ["scene.map.npz"]  # no temp file left


def test_a_map_of_nothing_is_refused_and_not_written(tmp_path):
    empty = Map(Ellipsoids.empty(), np.zeros(0, int), [], [], np.zeros(0, int))
    with pytest.raises(MapFileError, match=r"empty\.npz: 0 landmarks; a map holds 1 to"):
        save_map(empty, tmp_path / "empty.npz")
    assert list(tmp_path.iterdir()) == []


def test_missing_file_says_how_to_make_one(tmp_path):
    with pytest.raises(MapFileError, match=r"not found.*clipclique-map build"):
        load_map(tmp_path / "absent.map.npz")


def test_truncated_file_is_a_clear_error(tmp_path):
    path = tmp_path / "m.npz"
    save_map(make_map(), path)
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(MapFileError, match=r"m\.npz: not a readable map file"):
        load_map(path)


def test_foreign_npz_is_not_a_map(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, points=np.zeros((3, 3)))
    with pytest.raises(MapFileError, match="missing header"):
        load_map(path)


def test_newer_schema_version_asks_for_an_upgrade(tmp_path):
    path = tmp_path / "m.npz"
    save_map(make_map(), path)
    with np.load(path) as data:
        header = json.loads(str(data["header"][()]))
    header["schema_version"] = SCHEMA_VERSION + 1
    rewrite(path, header=np.array(json.dumps(header)))
    with pytest.raises(MapFileError, match=rf"schema version {SCHEMA_VERSION + 1} is newer.*upgrade"):
        load_map(path)


def test_inconsistent_shapes_are_rejected(tmp_path):
    path = tmp_path / "m.npz"
    save_map(make_map(n=5), path)
    rewrite(path, axes=np.ones((4, 3)))
    with pytest.raises(MapFileError, match=r"ellipsoid arrays disagree.*axes \(4, 3\)"):
        load_map(path)


def test_unnormalized_embeddings_are_rejected(tmp_path):
    path = tmp_path / "m.npz"
    save_map(make_map(), path)
    rewrite(path, text_embeddings=np.ones((5, 8), np.float32))
    with pytest.raises(MapFileError, match="L2-normalized"):
        load_map(path)


def test_pickled_arrays_are_never_loaded(tmp_path):
    path = tmp_path / "m.npz"
    save_map(make_map(), path)
    rewrite(path, class_ids=np.array([object()] * 5, dtype=object))
    with pytest.raises(MapFileError, match="holds Python objects"):
        load_map(path)
    assert zipfile.is_zipfile(path)


def test_save_refuses_an_inconsistent_map(tmp_path):
    broken = make_map()
    broken.encoder = "none"  # embeddings present but no encoder named
    with pytest.raises(MapFileError, match="encoder is 'none'"):
        save_map(broken, tmp_path / "m.npz")
    assert not list(tmp_path.iterdir())


def test_a_file_that_is_not_an_archive_is_named_as_such(tmp_path):
    path = tmp_path / "notes.map.npz"
    path.write_text("these are not arrays\n")
    with pytest.raises(MapFileError, match=r"notes\.map\.npz: not a readable map file \(not an \.npz archive"):
        load_map(path)


@pytest.mark.parametrize("name", ["centers", "text_embeddings"])
def test_text_where_numbers_belong_is_a_map_file_error(tmp_path, name):
    path = tmp_path / "m.npz"
    save_map(make_map(), path)
    with np.load(path) as data:
        rewrite(path, **{name: data[name].astype(str)})
    with pytest.raises(MapFileError, match=f"m.npz: {name}.*should be numbers"):  # was numpy's TypeError
        load_map(path)


def test_an_unwritable_output_is_a_map_file_error(tmp_path):
    (tmp_path / "taken.npz").mkdir()
    with pytest.raises(MapFileError, match=r"taken\.npz: cannot write the map file"):  # was IsADirectoryError
        save_map(make_map(), tmp_path / "taken.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.npz"]
