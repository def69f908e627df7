"""The map file: a versioned `.npz` of landmark arrays plus a JSON header, loaded without pickle.

Arrays: `centers` (N, 3), `axes` (N, 3) semi-axes in metres, `rotations` (N, 3, 3) axis
directions as columns, `class_ids` (N,), `instance_ids` (N,), optionally `text_embeddings`
(N, D) float32 L2-normalized, and `header`, a JSON string:
`{"format": "clipclique-map", "schema_version": 1, "class_names": [...], "descriptions": [...],
"encoder": "...", "provenance": {...}}`. Written to a temporary file and renamed, so a map file
is either complete or absent; every field is checked on load.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from clipclique.errors import MapFileError
from clipclique.types import Ellipsoids, Map

FORMAT = "clipclique-map"
SCHEMA_VERSION = 1
REQUIRED_ARRAYS = ("header", "centers", "axes", "rotations", "class_ids", "instance_ids")


def save_map(map: Map, path: Path) -> None:
    """Write `map` to `path` atomically (temp file in the same folder, then rename)."""
    path = Path(path)
    validate_map(map, str(path))
    header = {
        "format": FORMAT,
        "schema_version": SCHEMA_VERSION,
        "class_names": list(map.class_names),
        "descriptions": list(map.descriptions),
        "encoder": map.encoder,
        "provenance": map.provenance,
    }
    arrays = {
        "header": np.array(json.dumps(header)),
        "centers": np.asarray(map.ellipsoids.centers, np.float64),
        "axes": np.asarray(map.ellipsoids.axes, np.float64),
        "rotations": np.asarray(map.ellipsoids.rotations, np.float64),
        "class_ids": np.asarray(map.class_ids, np.int64),
        "instance_ids": np.asarray(map.instance_ids, np.int64),
    }
    if map.text_embeddings is not None:
        arrays["text_embeddings"] = np.asarray(map.text_embeddings, np.float32)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as error:
        raise MapFileError(f"{path}: cannot write the map file ({error.strerror or error})") from None
    try:
        with os.fdopen(handle, "wb") as stream:
            np.savez_compressed(stream, **arrays)
        os.chmod(temp, 0o644)  # mkstemp makes it private; a map is an ordinary output file
        os.replace(temp, path)
    except OSError as error:  # e.g. the path is a folder, or the disk is full
        Path(temp).unlink(missing_ok=True)
        raise MapFileError(f"{path}: cannot write the map file ({error.strerror or error})") from None
    except BaseException:
        Path(temp).unlink(missing_ok=True)
        raise


def load_map(path: Path) -> Map:
    """Read and validate a map file; MapFileError says what is wrong with which file."""
    path = Path(path)
    if not path.is_file():
        raise MapFileError(f"{path}: map file not found (build one with: clipclique-map build SCENE)")
    if not zipfile.is_zipfile(path):
        # np.load would take any other file for a pickle and say so in a confusing way
        raise MapFileError(f"{path}: not a readable map file (not an .npz archive, or a truncated one)")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [name for name in REQUIRED_ARRAYS if name not in data.files]
            if missing:
                raise MapFileError(f"{path}: not a clipclique map (missing {', '.join(missing)})")
            arrays = {name: data[name] for name in data.files}
    except MapFileError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise MapFileError(f"{path}: not a readable map file ({type(error).__name__}: {error})") from None
    header = _read_header(arrays["header"], path)
    embeddings = arrays.get("text_embeddings")
    map = Map(
        ellipsoids=Ellipsoids(arrays["centers"], arrays["axes"], arrays["rotations"]),
        class_ids=arrays["class_ids"],
        class_names=header["class_names"],
        descriptions=header["descriptions"],
        instance_ids=arrays["instance_ids"],
        text_embeddings=embeddings,
        encoder=header["encoder"],
        provenance=header["provenance"],
    )
    validate_map(map, str(path))
    return map


def _read_header(raw: np.ndarray, path: Path) -> dict:
    try:
        header = json.loads(str(raw[()]))
    except (json.JSONDecodeError, TypeError, IndexError) as error:
        raise MapFileError(f"{path}: header is not valid JSON ({error})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise MapFileError(f"{path}: not a clipclique map (header format is not {FORMAT!r})")
    version = header.get("schema_version")
    if version != SCHEMA_VERSION:
        hint = "newer than this clipclique reads; upgrade clipclique" if isinstance(version, int) and version > SCHEMA_VERSION else "not supported"
        raise MapFileError(f"{path}: map schema version {version!r} is {hint} (this version reads {SCHEMA_VERSION})")
    kinds = {"class_names": list, "descriptions": list, "encoder": str, "provenance": dict}
    for key, kind in kinds.items():
        if not isinstance(header.get(key), kind):
            raise MapFileError(f"{path}: header field {key!r} missing or not a {kind.__name__}")
    return header


def validate_map(map: Map, where: str) -> None:
    """Shapes, ranges and consistency of a map's fields; MapFileError naming `where` on the first problem."""

    def fail(problem: str) -> None:
        raise MapFileError(f"{where}: {problem}")

    e = map.ellipsoids
    n = len(e.centers)
    if np.shape(e.centers) != (n, 3) or np.shape(e.axes) != (n, 3) or np.shape(e.rotations) != (n, 3, 3):
        fail(f"ellipsoid arrays disagree: centers {np.shape(e.centers)}, axes {np.shape(e.axes)}, rotations {np.shape(e.rotations)}")
    for name, values in (("class_ids", map.class_ids), ("instance_ids", map.instance_ids)):
        if np.shape(values) != (n,) or np.asarray(values).dtype.kind not in "iu":
            fail(f"{name} should be {n} integers, got {np.asarray(values).dtype} {np.shape(values)}")
    if len(map.descriptions) != n or not all(isinstance(d, str) for d in map.descriptions):
        fail(f"{len(map.descriptions)} descriptions for {n} landmarks")
    if not all(isinstance(c, str) for c in map.class_names) or len(set(map.class_names)) != len(map.class_names):
        fail("class_names must be distinct strings")
    if n and (np.min(map.class_ids) < 0 or np.max(map.class_ids) >= len(map.class_names)):
        fail(f"class_ids outside the vocabulary of {len(map.class_names)} classes")
    for name, values in (("centers", e.centers), ("axes", e.axes), ("rotations", e.rotations)):
        if np.asarray(values).dtype.kind not in "fiu":
            fail(f"{name} should be numbers, got {np.asarray(values).dtype}")
    if not (np.isfinite(e.centers).all() and np.isfinite(e.rotations).all() and np.isfinite(e.axes).all()):
        fail("non-finite ellipsoid values")
    if n and np.min(e.axes) <= 0:
        fail("ellipsoid semi-axes must be positive")
    if n and not np.allclose(np.einsum("nji,njk->nik", e.rotations, e.rotations), np.eye(3), atol=1e-4):
        fail("ellipsoid rotations are not orthonormal")
    embeddings = map.text_embeddings
    if embeddings is None:
        if map.encoder != "none":
            fail(f"encoder {map.encoder!r} recorded but no text embeddings stored")
        return
    if map.encoder == "none":
        fail("text embeddings stored but encoder is 'none'")
    if np.ndim(embeddings) != 2 or len(embeddings) != n or np.asarray(embeddings).dtype.kind not in "fiu":
        fail(f"text_embeddings {np.asarray(embeddings).dtype} {np.shape(embeddings)} should be numbers, one row per landmark ({n})")
    if not np.isfinite(embeddings).all() or (n and not np.allclose(np.linalg.norm(embeddings, axis=1), 1.0, atol=1e-3)):
        fail("text embeddings must be finite and L2-normalized")
