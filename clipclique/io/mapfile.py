"""The map file: a versioned `.npz` of landmark arrays plus a JSON header, loaded without pickle.

Arrays: `centers` (N, 3), `axes` (N, 3) semi-axes in metres, `rotations` (N, 3, 3) axis
directions as columns, `class_ids` (N,), `instance_ids` (N,), optionally `text_embeddings`
(N, D) float32 L2-normalized and (schema 2) `class_distributions` (N, C) float64 rows summing
to 1, and `header`, a JSON string:
`{"format": "clipclique-map", "schema_version": 2, "class_names": [...], "descriptions": [...],
"encoder": "...", "provenance": {...}}`. Schema 1 files (no class distributions) still load. Written to a temporary file
and renamed, so a map file is either complete or absent; every field is checked on load.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from clipclique.errors import MapFileError
from clipclique.io.safeio import check_text, parse_json
from clipclique.types import Ellipsoids, Map

FORMAT = "clipclique-map"
SCHEMA_VERSION = 2
READABLE_VERSIONS = (1, 2)  # 2 added the optional class_distributions
REQUIRED_ARRAYS = ("header", "centers", "axes", "rotations", "class_ids", "instance_ids")
# Far beyond any real map (ScanNet scenes hold under 100 objects), and small enough that nothing
# built from a map (descriptors, recordings) can exhaust memory or time.
MAX_LANDMARKS = 100_000
MAX_CLASSES = 1000  # Semantic Histogram codes are C^s: 1000^6 still fits int64
MAX_EMBEDDING_DIM = 4096
MAX_COORDINATE_M = 1e5  # 100 km
MAX_ARRAY_BYTES = 1 << 30


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
    if map.class_distributions is not None:
        arrays["class_distributions"] = np.asarray(map.class_distributions, np.float64)
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
    if path.is_dir():
        raise MapFileError(f"{path}: is a folder, expected a map file")
    if not path.is_file():
        raise MapFileError(f"{path}: map file not found (build one with: clipclique-map build SCENE)")
    if not zipfile.is_zipfile(path):
        # np.load would take any other file for a pickle and say so in a confusing way
        raise MapFileError(f"{path}: not a readable map file (not an .npz archive, or a truncated one)")
    try:
        _check_declared_arrays(path)
        with np.load(path, allow_pickle=False) as data:
            missing = [name for name in REQUIRED_ARRAYS if name not in data.files]
            if missing:
                raise MapFileError(f"{path}: not a clipclique map (missing {', '.join(missing)})")
            arrays = {name: data[name] for name in data.files}
    except MapFileError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, zlib.error, EOFError, RuntimeError) as error:
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
        class_distributions=arrays.get("class_distributions"),
    )
    validate_map(map, str(path))
    return map


def _check_declared_arrays(path: Path) -> None:
    """Refuse, before decompressing anything, arrays whose declared dtype or size no map has.

    An .npz member's header declares its shape; numpy would allocate that much before reading
    a byte of data (a declared 3e12 elements is a 24 TB request).
    """
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            with archive.open(info) as member:
                version = np.lib.format.read_magic(member)
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                shape, _, dtype = read(member)
            name = info.filename.removesuffix(".npy")
            if dtype.hasobject:
                raise MapFileError(f"{path}: array {name!r} holds Python objects; a map holds numbers and text only")
            size = math.prod(shape) * dtype.itemsize
            if size > MAX_ARRAY_BYTES:
                raise MapFileError(f"{path}: array {name!r} declares shape {shape} ({size / 2**20:.0f} MiB), "
                                   f"more than the {MAX_ARRAY_BYTES / 2**20:.0f} MiB a map array may hold")


def _read_header(raw: np.ndarray, path: Path) -> dict:
    if raw.dtype.kind != "U" or raw.shape != ():
        raise MapFileError(f"{path}: header is not a JSON string ({raw.dtype} {raw.shape})")
    header = parse_json(str(raw[()]), f"{path}: header", MapFileError)
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise MapFileError(f"{path}: not a clipclique map (header format is not {FORMAT!r})")
    version = header.get("schema_version")
    if version not in READABLE_VERSIONS:
        hint = ("newer than this clipclique reads; upgrade clipclique"
                if isinstance(version, int) and version > SCHEMA_VERSION else "not supported")
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
    if not 1 <= n <= MAX_LANDMARKS:
        fail(f"{n} landmarks; a map holds 1 to {MAX_LANDMARKS}")
    if np.shape(e.centers) != (n, 3) or np.shape(e.axes) != (n, 3) or np.shape(e.rotations) != (n, 3, 3):
        fail(f"ellipsoid arrays disagree: centers {np.shape(e.centers)}, axes {np.shape(e.axes)}, rotations "
             f"{np.shape(e.rotations)}")
    for name, values in (("class_ids", map.class_ids), ("instance_ids", map.instance_ids)):
        if np.shape(values) != (n,) or np.asarray(values).dtype.kind not in "iu":
            fail(f"{name} should be {n} integers, got {np.asarray(values).dtype} {np.shape(values)}")
    if len(map.descriptions) != n:
        fail(f"{len(map.descriptions)} descriptions for {n} landmarks")
    if not 1 <= len(map.class_names) <= MAX_CLASSES:
        fail(f"{len(map.class_names)} class names; a map's vocabulary holds 1 to {MAX_CLASSES}")
    for kind, texts in (("class name", map.class_names), ("description", map.descriptions)):
        for text in texts:
            check_text(text, f"{where}: {kind}", MapFileError)
    check_text(map.encoder, f"{where}: encoder", MapFileError)
    if len(set(map.class_names)) != len(map.class_names):
        fail("class_names must be distinct strings")
    if np.min(map.class_ids) < 0 or np.max(map.class_ids) >= len(map.class_names):
        fail(f"class_ids outside the vocabulary of {len(map.class_names)} classes")
    for name, values in (("centers", e.centers), ("axes", e.axes), ("rotations", e.rotations)):
        if np.asarray(values).dtype.kind not in "fiu":
            fail(f"{name} should be numbers, got {np.asarray(values).dtype}")
    if not (np.isfinite(e.centers).all() and np.isfinite(e.rotations).all() and np.isfinite(e.axes).all()):
        fail("non-finite ellipsoid values")
    if np.max(np.abs(e.centers)) > MAX_COORDINATE_M or np.max(e.axes) > MAX_COORDINATE_M:
        fail(f"ellipsoid centres or axes beyond {MAX_COORDINATE_M:g} m; is the map in metres?")
    if np.min(e.axes) <= 0:
        fail("ellipsoid semi-axes must be positive")
    if not np.allclose(np.einsum("nji,njk->nik", e.rotations, e.rotations), np.eye(3), atol=1e-4):
        fail("ellipsoid rotations are not orthonormal")
    if (np.linalg.det(e.rotations) < 0).any():
        fail(f"ellipsoid rotation {int(np.argmax(np.linalg.det(e.rotations) < 0))} is a reflection (determinant -1)")
    _validate_distributions(map, fail)
    embeddings = map.text_embeddings
    if embeddings is None:
        if map.encoder != "none":
            fail(f"encoder {map.encoder!r} recorded but no text embeddings stored")
        return
    if map.encoder == "none":
        fail("text embeddings stored but encoder is 'none'")
    if (np.ndim(embeddings) != 2 or len(embeddings) != n or not 1 <= np.shape(embeddings)[1] <= MAX_EMBEDDING_DIM
        or np.asarray(embeddings).dtype.kind not in "fiu"):
        fail(f"text_embeddings {np.asarray(embeddings).dtype} {np.shape(embeddings)} should be numbers, one row per "
             f"landmark ({n})")
    if not np.isfinite(embeddings).all() or (not np.allclose(np.linalg.norm(embeddings, axis=1), 1.0, atol=1e-3)):
        fail("text embeddings must be finite and L2-normalized")


def _validate_distributions(map: Map, fail: Callable[[str], None]) -> None:
    """Class distributions, when present: (N, C) finite probabilities, rows summing to 1."""
    distributions = map.class_distributions
    if distributions is None:
        return
    shape = (len(map.class_ids), len(map.class_names))
    if np.shape(distributions) != shape or np.asarray(distributions).dtype.kind not in "fiu":
        fail(f"class_distributions {np.asarray(distributions).dtype} {np.shape(distributions)} should be "
             f"numbers of shape {shape}")
    if not np.isfinite(distributions).all() or (np.asarray(distributions) < 0).any():
        fail("class_distributions must be finite and non-negative")
    if not np.allclose(np.sum(distributions, axis=1), 1.0, atol=1e-3):
        fail("class_distributions rows must sum to 1")
