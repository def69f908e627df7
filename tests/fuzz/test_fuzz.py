"""Hostile and broken inputs against clipclique-map, clipclique-loc run and compare (issue 12).

Every case is generated from a small demo (4 frames of 160 x 120, ScanNet and TUM layouts) by
one deterministic mutation, and run in-process. Each must end with exit code 2 and one line
that names the input, no traceback, no `*.partial`/`*.tmp` left anywhere, and the earlier map,
recording and results byte-identical.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
import shutil
import struct
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from clipclique.interop.coco import encode_rle
from clipclique.localization.cli import app as loc_app
from clipclique.mapping.cli import app as map_app

RUNNER = CliRunner()
PWNED = Path("/tmp/clipclique-fuzz-pickle-ran")  # what the hostile pickles would create if ever loaded


@dataclass(frozen=True)
class Case:
    """One hostile input: `make(workspace, case_dir)` writes it and returns (app, args, text the message must name)."""

    family: str
    name: str
    make: Callable[[Workspace, Path], tuple[object, list[str], str]]

    def __str__(self) -> str:
        return f"{self.family}-{self.name}"


@dataclass
class Workspace:
    root: Path  # data/ (the demos), maps/ (a map and its recording), loc/ (an earlier run's outputs)

    @property
    def data(self) -> Path:
        return self.root / "data"

    @property
    def map(self) -> Path:
        return self.root / "maps" / "demo.map.npz"

    @property
    def loc(self) -> Path:
        return self.root / "loc"

    def copy(self, scene: str, case_dir: Path) -> Path:
        """A private copy of a demo scene folder to mutate."""
        target = case_dir / scene
        shutil.copytree(self.data / "demo" / scene, target)
        return target

    def loc_args(self, *extra: str, sequence: str = "demo", map_path: Path | None = None) -> list[str]:
        return ["run", sequence, "--data-root", str(self.data), "--map", str(map_path or self.map), "--out",
                str(self.loc),
                "--max-frames", "2", *extra]

    def map_args(self, scene: str, *extra: str) -> list[str]:
        return ["build", scene, "--data-root", str(self.data), "--out", str(self.map), "--encoder", "simulated", *extra]


@pytest.fixture(scope="module")
def workspace(tmp_path_factory, demo_data) -> Workspace:
    """The two small demos, a map with a recording, and a successful earlier run (with its recording)."""
    space = Workspace(tmp_path_factory.mktemp("fuzz"))
    space.data.symlink_to(demo_data("demo", "demo_tum"), target_is_directory=True)  # shared: cases mutate copies
    built = RUNNER.invoke(map_app, space.map_args("demo"))
    assert built.exit_code == 0, built.output
    ran = RUNNER.invoke(loc_app, space.loc_args())
    assert ran.exit_code == 0, ran.output
    assert ({p.name for p in space.loc.iterdir()}
            == {"results.json", "frames.csv", "poses.tum", "groundtruth.tum", "config.json", "recording.rrd"})
    return space


def snapshot(*folders: Path) -> dict[str, str]:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for folder in folders
            for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(root: Path) -> list[str]:
    return [str(p) for p in root.rglob("*") if p.name.endswith((".partial", ".tmp"))]


# ---- mutations -----------------------------------------------------------------------------------

LATIN1 = "café".encode("latin-1")


def _insert(path: Path, data: bytes, at: float = 0.5) -> None:
    raw = path.read_bytes()
    cut = int(len(raw) * at)
    cut = raw.rfind(b"\n", 0, cut) + 1 if b"\n" in raw[:cut] else cut
    path.write_bytes(raw[:cut] + data + raw[cut:])


def _replace_dir(path: Path) -> None:
    path.unlink()
    path.mkdir()


def _deep_json(depth: int = 100_000) -> str:
    return "[" * depth + "]" * depth


def _map_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


def _rewrite_map(space: Workspace, case_dir: Path, edit: Callable[[dict], None] | None = None, **arrays) -> Path:
    """A copy of the good map with some arrays replaced, or its header fields edited."""
    contents = _map_arrays(space.map)
    if edit is not None:
        fields = json.loads(str(contents["header"][()]))
        edit(fields)
        contents["header"] = np.array(json.dumps(fields))
    contents.update(arrays)
    target = case_dir / "bad.map.npz"
    np.savez(target, **contents)
    return target


def _npy_declaring(shape: tuple[int, ...]) -> bytes:
    """An .npy member whose header declares `shape` but holds 24 bytes of data."""
    header = f"{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}".encode()
    header += b" " * (63 - (len(header) + 10) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + bytes(24)


def map_cases() -> list[Case]:
    """A damaged or hostile map file given to clipclique-loc run --map."""

    def use(make_map: Callable[[Workspace, Path], Path]) -> Callable:
        def make(space: Workspace, case_dir: Path):
            path = make_map(space, case_dir)
            return loc_app, space.loc_args(map_path=path), path.name

        return make

    def raw(data: bytes) -> Callable[[Workspace, Path], Path]:
        def write(space: Workspace, case_dir: Path) -> Path:
            (case_dir / "bad.map.npz").write_bytes(data)
            return case_dir / "bad.map.npz"

        return write

    def truncated(fraction: float):
        def write(space, case_dir):
            data = space.map.read_bytes()
            return raw(data[: int(len(data) * fraction)])(space, case_dir)

        return write

    def flipped(seed: int):
        """Bytes flipped inside a member's compressed data: a corrupt deflate stream or a CRC mismatch."""

        def write(space, case_dir):
            data = bytearray(space.map.read_bytes())
            with zipfile.ZipFile(space.map) as archive:
                info = archive.infolist()[seed % len(archive.infolist())]
            start = info.header_offset + 30 + len(info.filename) + len(info.extra)
            rng = np.random.default_rng(seed)
            for offset in rng.integers(start, start + info.compress_size, 4):
                data[offset] ^= 0xFF
            return raw(bytes(data))(space, case_dir)

        return write

    def declared(shape: tuple[int, ...]):
        def write(space, case_dir):
            target = case_dir / "bad.map.npz"
            with zipfile.ZipFile(space.map) as source, zipfile.ZipFile(target, "w") as archive:
                for info in source.infolist():
                    body = _npy_declaring(shape) if info.filename == "centers.npy" else source.read(info)
                    archive.writestr(info.filename, body)
            return target

        return write

    def rotations(matrix_of: Callable[[np.ndarray], np.ndarray]):
        return lambda space, case_dir: _rewrite_map(space, case_dir,
                                                    rotations=matrix_of(_map_arrays(space.map)["rotations"]))

    def reflect(r: np.ndarray) -> np.ndarray:
        r = r.copy()
        r[0, :, 0] *= -1
        return r

    def centers(value: float):
        def write(space, case_dir):
            c = _map_arrays(space.map)["centers"].copy()
            c[0, 0] = value
            return _rewrite_map(space, case_dir, centers=c)

        return write

    def header(change: Callable[[dict], None]):
        return lambda space, case_dir: _rewrite_map(space, case_dir, edit=change)

    def vocabulary(space, case_dir):
        return _rewrite_map(space, case_dir,
                            edit=lambda h: h.__setitem__("class_names",
                                                         h["class_names"] + [f"c{i}" for i in range(200_000)]))

    def empty(space, case_dir):
        return _rewrite_map(space, case_dir, edit=lambda h: h.update(class_names=[], descriptions=[]),
                            centers=np.zeros((0, 3)), axes=np.zeros((0, 3)), rotations=np.zeros((0, 3, 3)),
                            class_ids=np.zeros(0, np.int64), instance_ids=np.zeros(0, np.int64),
                            text_embeddings=np.zeros((0, 512), np.float32))

    def pickled(space, case_dir):
        return _rewrite_map(space, case_dir, class_ids=np.array([object()], dtype=object))

    def folder(space, case_dir):
        (case_dir / "bad.map.npz").mkdir()
        return case_dir / "bad.map.npz"

    rng = np.random.default_rng(12)
    makers: dict[str, Callable] = {
        **{f"random-bytes-{i}": raw(rng.bytes(2000 * (i + 1))) for i in range(3)},
        "empty-file": raw(b""),
        **{f"truncated-{f}": truncated(f) for f in (0.1, 0.3, 0.5, 0.7, 0.9, 0.99)},
        **{f"corrupt-deflate-{seed}": flipped(seed) for seed in range(6)},
        "declared-shape-3e12": declared((3_000_000_000_000, 3)),
        "declared-shape-2**62": declared((2**62, 3)),
        "object-array": pickled,
        "reflection": rotations(reflect),
        "scaled-rotation": rotations(lambda r: r * 2),
        "nan-rotation": rotations(lambda r: np.where(np.arange(r.size).reshape(r.shape) == 0, np.nan, r)),
        "coordinate-1e300": centers(1e300),
        "coordinate-nan": centers(np.nan),
        "coordinate-inf": centers(-np.inf),
        "zero-landmarks": empty,
        "huge-vocabulary": vocabulary,
        "header-deep-json": lambda space, case_dir: _rewrite_map(space, case_dir, header=np.array(_deep_json())),
        "header-not-json": lambda space, case_dir: _rewrite_map(space, case_dir, header=np.array("{not json")),
        "header-bytes": lambda space, case_dir: _rewrite_map(space, case_dir,
                                                             header=np.frombuffer(b"\x00\xff" * 8, np.uint8)),
        "schema-version-3": header(lambda h: h.update(schema_version=3)),
        "class-name-nul": header(lambda h: h["class_names"].__setitem__(0, "ch\0air")),
        "class-name-not-text": header(lambda h: h["class_names"].__setitem__(0, 7)),
        "description-megabyte": header(lambda h: h["descriptions"].__setitem__(0, "x" * 1_000_000)),
        "provenance-deep": header(lambda h: h.update(provenance={"a": json.loads("[" * 100 + "]" * 100)})),
        "map-is-a-folder": folder,
    }
    return [Case("map", name, use(make)) for name, make in makers.items()]


FLOAT_KEYS = ("inliers.d_comp", "graph.d_adj", "matching.top_m_fraction", "similarity.alpha", "inliers.time_limit_s",
              "inliers.inlier_threshold", "matching.min_similarity", "success_threshold_m", "pose.min_conditioning")


def config_cases() -> list[Case]:
    """Numbers out of range in --set, and broken --config files."""

    def override(assignment: str, key: str) -> Callable:
        return lambda space, case_dir: (loc_app, space.loc_args("--set", assignment), key)

    def config_file(data: bytes | None, directory: bool = False, name: str = "params.toml") -> Callable:
        def make(space, case_dir):
            path = case_dir / name
            path.mkdir() if directory else path.write_bytes(data)
            return loc_app, space.loc_args("--config", str(path)), name

        return make

    cases = [Case("config", f"{key}={value}", override(f"{key}={value}", key)) for key in FLOAT_KEYS
             for value in ("nan", "inf", "-inf")]
    for assignment in ("graph.walk_length=40", "graph.walk_length=0", "inliers.seed=-1", "graph.xview_seed=-3",
                       "top_n=0", "top_n=100000000000000000000", "matching.k=-2", "inliers.min_clique_size=2",
                       "matching.top_m_fraction=1.5", "graph.xview_walks=1000000000", "method=xyz",
                       "observations.max_depth=-1", "observations.fit.min_points=0", "matching.max_candidates=0",
                       "verification.explained_iou=2", "inliers.max_pairs=-5"):
        cases.append(Case("config", assignment, override(assignment, assignment.partition("=")[0])))
    cases += [
        Case("config", "toml-latin1", config_file(b"[inliers]\n# " + LATIN1 + b"\nd_comp = 0.3\n")),
        Case("config", "toml-nul", config_file(b"[inliers]\nd_comp = 0.3\0\n")),
        Case("config", "toml-deep", config_file(("x = " + "[" * 100_000 + "]" * 100_000).encode())),
        Case("config", "toml-folder", config_file(None, directory=True)),
        Case("config", "toml-nan", config_file(b"[graph]\nd_adj = nan\n")),
        Case("config", "json-list", config_file(b"[1, 2]", name="config.json")),
        Case("config", "json-latin1", config_file(b'{"method": "' + LATIN1 + b'"}', name="config.json")),
        Case("config", "json-deep", config_file(b"[" * 100_000 + b"]" * 100_000, name="config.json")),
        Case("config", "json-nan", config_file(b'{"graph": {"d_adj": NaN}}', name="config.json")),
        Case("config", "json-null", config_file(b'{"inliers": {"d_comp": null}}', name="config.json")),
        Case("config", "json-section-as-key", config_file(b'{"observations": {"fit": 3}}', name="config.json")),
    ]
    return cases


def tum_cases() -> list[Case]:
    """A TUM sequence (the small demo_tum) with one file broken, given to clipclique-map build."""

    def mutated(relative: str, change: Callable[[Path], None], names: str | None = None) -> Callable:
        def make(space, case_dir):
            folder = space.copy("demo_tum", case_dir)
            change(folder / relative)
            return map_app, space.map_args(str(folder)), names or Path(relative).name

        return make

    def first_instance(folder_file: Path) -> Path:
        return sorted(folder_file.glob("*.png"))[0]

    files = ("groundtruth.txt", "rgb.txt", "depth.txt", "intrinsics.txt", "annotations/objects.csv")
    cases = []
    for relative in files:
        cases += [
            Case("tum-text", f"{relative}-latin1", mutated(relative, lambda p: _insert(p, b"# " + LATIN1 + b"\n"))),
            Case("tum-text", f"{relative}-nul", mutated(relative, lambda p: _insert(p, b"\0\n", 0.9))),
            Case("tum-text", f"{relative}-folder", mutated(relative, _replace_dir)),
            Case("tum-text", f"{relative}-utf16",
                 mutated(relative, lambda p: p.write_bytes(p.read_text().encode("utf-16")))),
        ]
    objects = "annotations/objects.csv"
    cases += [
        Case("tum-data", "rgb-empty", mutated("rgb.txt", lambda p: p.write_text("# timestamp filename\n"))),
        Case("tum-data", "rgb-escape", mutated("rgb.txt",
                                               lambda p: _insert(p, b"1700000000.0 ../../../etc/passwd\n", 0.99))),
        Case("tum-data", "groundtruth-nan",
             mutated("groundtruth.txt", lambda p: _insert(p, b"1700000000.5 nan 0 0 0 0 0 1\n", 0.99))),
        Case("tum-data", "intrinsics-negative", mutated("intrinsics.txt", lambda p: p.write_text("-500 500 80 60\n"))),
        Case("tum-data", "objects-id-2**70",
             mutated(objects, lambda p: _insert(p, f'{2**70},chair,"a chair"\n'.encode(), 0.99))),
        Case("tum-data", "objects-id-0", mutated(objects, lambda p: _insert(p, b'0,chair,"a chair"\n', 0.99))),
        Case("tum-data", "objects-id-duplicate",
             mutated(objects, lambda p: p.write_text(p.read_text() + p.read_text().splitlines()[1] + "\n"))),
        Case("tum-data", "objects-class-escape",
             mutated(objects, lambda p: _insert(p, b'99,ch\x1bair,"a chair"\n', 0.99))),
        Case("tum-data", "objects-no-header", mutated(objects, lambda p: p.write_text("7,desk,a desk\n"))),
        Case("tum-image", "instance-rgb",
             mutated("annotations/instances", lambda p: Image.new("RGB", (160, 120)).save(first_instance(p)),
                     "instances")),
        Case("tum-image", "instance-junk",
             mutated("annotations/instances", lambda p: first_instance(p).write_bytes(b"\x89PNG junk"), "instances")),
        Case("tum-image", "instance-folder",
             mutated("annotations/instances", lambda p: _replace_dir(first_instance(p)), "instances")),
    ]
    return cases


def annotate_cases() -> list[Case]:
    """The small demo_tum's masks and objects table, moved out of it and one broken, given to clipclique-map
    annotate."""

    def mutated(change: Callable[[Path, Path], None], names: str) -> Callable:
        def make(space, case_dir):
            folder = space.copy("demo_tum", case_dir)
            masks, table = case_dir / "masks", case_dir / "classes.csv"
            (folder / "annotations" / "instances").rename(masks)
            (folder / "annotations" / "objects.csv").rename(table)
            (folder / "annotations").rmdir()
            change(masks, table)
            return map_app, ["annotate", str(folder), "--masks", str(masks), "--objects", str(table)], names

        return make

    def renamed(stem: str) -> Callable[[Path, Path], None]:
        return lambda masks, table: sorted(masks.glob("*.png"))[0].rename(masks / f"{stem}.png")

    def first(masks: Path) -> Path:
        return sorted(masks.glob("*.png"))[0]

    cases = [Case("annotate", f"mask-named-{stem}", mutated(renamed(stem), f"{stem}.png"))
             for stem in ("inf", "-nan", "1e999", "0x1p30", "frame_0001", "9" * 240)]
    cases += [
        Case("annotate", "mask-rgb", mutated(lambda m, t: Image.new("RGB", (160, 120)).save(first(m)), "masks")),
        Case("annotate", "mask-junk", mutated(lambda m, t: first(m).write_bytes(b"\x89PNG junk"), "masks")),
        Case("annotate", "mask-folder", mutated(lambda m, t: _replace_dir(first(m)), "masks")),
        Case("annotate", "masks-none", mutated(lambda m, t: shutil.rmtree(m), "masks")),
        Case("annotate", "objects-latin1", mutated(lambda m, t: _insert(t, b"# " + LATIN1 + b"\n"), "classes.csv")),
        Case("annotate", "objects-missing-id",
             mutated(lambda m, t: t.write_text("id,class,description\n"), "classes.csv")),
    ]

    def coco(change: Callable[[dict], None]) -> Callable:
        """The demo_tum's first mask as a COCO annotation file (RLE), one thing in it broken."""
        def make(space, case_dir):
            folder = space.copy("demo_tum", case_dir)
            instances = sorted((folder / "annotations" / "instances").glob("*.png"))[0]
            ids = np.asarray(Image.open(instances))
            shutil.rmtree(folder / "annotations")
            object_id = int(ids.max())
            document = {"images": [{"id": 1, "file_name": f"rgb/{instances.stem}.png", "width": ids.shape[1],
                                    "height": ids.shape[0]}],
                        "categories": [{"id": 3, "name": "cup"}],
                        "annotations": [{"id": 1, "image_id": 1, "category_id": 3, "track_id": object_id,
                                         "segmentation": encode_rle(ids == object_id)}]}
            change(document)
            path = case_dir / "instances.json"
            path.write_text(json.dumps(document))
            return map_app, ["annotate", str(folder), "--coco", str(path)], "instances.json"

        return make

    def annotation(**change) -> Callable[[dict], None]:
        return lambda document: document["annotations"][0].update(change)

    cases += [Case("annotate", f"coco-{name}", coco(change)) for name, change in {
        "no-object-id": lambda d: d["annotations"][0].pop("track_id"),
        "object-id-text": annotation(track_id="seven"),
        "object-id-zero": annotation(track_id=0),
        "category-unknown": annotation(category_id=9),
        "image-unknown": annotation(image_id=2),
        "rle-other-size": annotation(segmentation={"size": [10, 10], "counts": [100]}),
        "polygon-two-points": annotation(segmentation=[[1, 1, 5, 5]]),
        "polygon-nan": annotation(segmentation=[[1, 1, 5, 5, float("nan"), 3]]),
        "no-images": lambda d: d.pop("images"),
        "image-no-size": lambda d: d["images"][0].pop("width"),
        "image-names-no-frame": lambda d: d["images"][0].update(file_name="rgb/photo.png"),
        "one-object-two-classes": lambda d: (d["categories"].append({"id": 4, "name": "bottle"}),
                                             d["annotations"].append(d["annotations"][0]
                                                                     | {"id": 2, "category_id": 4})),
    }.items()]
    return cases


def _aggregation(change: Callable[[dict], None]) -> Callable[[Path], None]:
    def write(path: Path) -> None:
        document = json.loads(path.read_text())
        change(document)
        path.write_text(json.dumps(document))

    return write


def scannet_cases() -> list[Case]:
    """The demo ScanNet scene with its segmentation, aggregation, descriptions or label table broken (map build)."""

    def mutated(relative: str, change: Callable[[Path], None]) -> Callable:
        def make(space, case_dir):
            folder = space.copy("demo", case_dir)
            change(folder / relative)
            return map_app, space.map_args(str(folder)), Path(relative).name

        return make

    aggregation, segs, descriptions = ("demo.aggregation.json", "demo_vh_clean_2.0.010000.segs.json",
                                       "demo_descriptions.json")
    groups = lambda change: _aggregation(lambda d: change(d["segGroups"]))  # noqa: E731
    tsv = "scannetv2-labels.combined.tsv"
    cases = {
        "aggregation-deep": (aggregation, lambda p: p.write_text(_deep_json())),
        "aggregation-list": (aggregation, lambda p: p.write_text("[1, 2]")),
        "aggregation-latin1": (aggregation, lambda p: _insert(p, LATIN1, 0.0)),
        "aggregation-2d-segments": (aggregation, groups(lambda g: g[0].update(segments=[g[0]["segments"]]))),
        "aggregation-duplicate-objectid": (aggregation, groups(lambda g: g[1].update(objectId=g[0]["objectId"]))),
        "aggregation-objectid-2**70": (aggregation, groups(lambda g: g[0].update(objectId=2**70))),
        "aggregation-objectid-negative": (aggregation, groups(lambda g: g[0].update(objectId=-5))),
        "aggregation-objectid-text": (aggregation, groups(lambda g: g[0].update(objectId="seven"))),
        "aggregation-label-nul": (aggregation, groups(lambda g: g[0].update(label="ch\0air"))),
        "aggregation-groups-dict": (aggregation, _aggregation(lambda d: d.update(segGroups={"a": 1}))),
        "segs-deep": (segs, lambda p: p.write_text('{"segIndices": ' + _deep_json() + "}")),
        "segs-float-ids": (segs, _aggregation(lambda d: d.update(segIndices=[i + 0.5 for i in d["segIndices"]]))),
        "segs-text-ids": (segs, _aggregation(lambda d: d["segIndices"].__setitem__(3, "x"))),
        "segs-huge-id": (segs, _aggregation(lambda d: d["segIndices"].__setitem__(3, 2**70))),
        "segs-folder": (segs, _replace_dir),
        "descriptions-nul": (descriptions, lambda p: p.write_text(json.dumps({"0": "a red\u0000 chair"}))),
        "descriptions-list": (descriptions, lambda p: p.write_text("[]")),
        "descriptions-latin1": (descriptions, lambda p: p.write_bytes(b'{"0": "a ' + LATIN1 + b' chair"}')),
        "labels-tsv-latin1": (tsv, lambda p: p.write_bytes(b"raw_category\tnyu40class\n" + LATIN1 + b"\tchair\n")),
        "labels-tsv-columns": (tsv, lambda p: p.write_text("a\tb\n1\t2\n")),
        "labels-tsv-folder": (tsv, lambda p: p.mkdir()),
        "descriptions-folder": (descriptions, _replace_dir),
        "mesh-junk": ("demo_vh_clean_2.labels.ply", lambda p: p.write_bytes(b"ply\nformat junk\n")),
    }
    return [Case("scannet", name, mutated(relative, change)) for name, (relative, change) in cases.items()]


def frame_cases() -> list[Case]:
    """The demo ScanNet scene with a pose, the intrinsics or a frame image broken (clipclique-loc run, recording on)."""

    def mutated(relative: str, change: Callable[[Path], None]) -> Callable:
        def make(space, case_dir):
            folder = space.copy("demo", case_dir)
            change(folder / relative)
            return loc_app, space.loc_args(sequence=str(folder)), Path(relative).name

        return make

    def matrix(values: np.ndarray) -> Callable[[Path], None]:
        return lambda p: np.savetxt(p, values)

    def huge_png(path: Path) -> None:
        """A PNG whose header declares 100,000 x 100,000 pixels (a decompression bomb)."""
        def chunk(kind: bytes, body: bytes) -> bytes:
            return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

        header = struct.pack(">IIBBBBB", 100_000, 100_000, 16, 0, 0, 0, 0)
        path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 100))
                         + chunk(b"IEND", b""))

    scaled = np.eye(4)
    scaled[:3, :3] *= 1.5
    reflected = np.diag([1.0, 1.0, -1.0, 1.0])
    sheared = np.eye(4)
    sheared[0, 1] = 0.4
    cases = {
        "pose-latin1": ("pose/1.txt", lambda p: _insert(p, LATIN1 + b"\n", 0.0)),
        "pose-scaled": ("pose/1.txt", matrix(scaled)),
        "pose-reflection": ("pose/1.txt", matrix(reflected)),
        "pose-shear": ("pose/1.txt", matrix(sheared)),
        "pose-3x3": ("pose/1.txt", matrix(np.eye(3))),
        "pose-text": ("pose/1.txt", lambda p: p.write_text("one two three four\n" * 4)),
        "intrinsics-latin1": ("intrinsic/intrinsic_depth.txt", lambda p: _insert(p, LATIN1 + b"\n", 0.0)),
        "intrinsics-garbage": ("intrinsic/intrinsic_depth.txt", lambda p: p.write_text("1 2\n3\n")),
        "intrinsics-other-camera": ("intrinsic/intrinsic_depth.txt",
                                    matrix(np.array([[500.0, 0, 700, 0], [0, 500, 20, 0], [0, 0, 1, 0],
                                                     [0, 0, 0, 1]]))),
        "intrinsics-folder": ("intrinsic/intrinsic_depth.txt", _replace_dir),
        "depth-8bit": ("depth/1.png", lambda p: Image.fromarray(np.full((120, 160), 200, np.uint8)).save(p)),
        "depth-rgb": ("depth/1.png", lambda p: Image.new("RGB", (160, 120)).save(p)),
        "depth-bomb": ("depth/1.png", huge_png),
        "depth-junk": ("depth/1.png", lambda p: p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))),
        "depth-truncated": ("depth/1.png", lambda p: p.write_bytes(p.read_bytes()[:120])),
        "depth-folder": ("depth/1.png", _replace_dir),
        "colour-junk": ("color/1.jpg", lambda p: p.write_bytes(b"\xff\xd8\xff not a jpeg")),
        "instance-rgb": ("instance-filt/1.png", lambda p: Image.new("RGB", (160, 120)).save(p)),
        "instance-rgba": ("instance-filt/1.png", lambda p: Image.new("RGBA", (160, 120)).save(p)),
        "instance-folder": ("instance-filt/1.png", _replace_dir),
    }
    return [Case("frames", name, mutated(relative, change)) for name, (relative, change) in cases.items()]


def output_cases() -> list[Case]:
    """Outputs that cannot be written where asked: a folder in the way, --out a file."""

    def loc_in_the_way(name: str) -> Callable:
        def make(space, case_dir):
            out = case_dir / "loc"
            shutil.copytree(space.loc, out)
            target = out / name
            target.unlink()
            target.mkdir()
            args = space.loc_args()
            args[args.index("--out") + 1] = str(out)
            return loc_app, args, name

        return make

    def out_is_file(space, case_dir):
        (case_dir / "file").write_text("x")
        args = space.loc_args()
        args[args.index("--out") + 1] = str(case_dir / "file")
        return loc_app, args, "file"

    def map_out_folder(space, case_dir):
        (case_dir / "m.map.npz").mkdir()
        args = space.map_args("demo")
        args[args.index("--out") + 1] = str(case_dir / "m.map.npz")
        return map_app, args, "m.map.npz"

    def map_recording_folder(space, case_dir):
        (case_dir / "m.map.rrd").mkdir()
        args = space.map_args("demo")
        args[args.index("--out") + 1] = str(case_dir / "m.map.npz")
        return map_app, args, "m.map.rrd"

    cases = [Case("outputs", f"{name}-is-a-folder", loc_in_the_way(name))
             for name in ("results.json", "frames.csv", "poses.tum", "groundtruth.tum", "config.json", "recording.rrd")]
    return cases + [Case("outputs", "out-is-a-file", out_is_file),
                    Case("outputs", "map-out-is-a-folder", map_out_folder),
                    Case("outputs", "map-recording-is-a-folder", map_recording_folder)]


def encoder_cases() -> list[Case]:
    """--encoder checkpoints that are junk, raw pickles (never run) or pickles referring to code."""

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {PWNED}",))

    def checkpoint(name: str, data: bytes | None) -> Callable:
        def make(space, case_dir):
            path = case_dir / name
            path.mkdir() if data is None else path.write_bytes(data)
            return map_app, [*space.map_args("demo")[:-2], "--encoder", str(path)], name

        return make

    archive = io.BytesIO()
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("weights/data.pkl", pickle.dumps(Evil(), protocol=2))
    return [
        Case("encoder", "junk-pt", checkpoint("junk.pt", bytes(range(256)) * 8)),
        Case("encoder", "raw-pickle", checkpoint("evil.pth", pickle.dumps(Evil()))),
        Case("encoder", "zip-pickle-with-code", checkpoint("evil.pt", archive.getvalue())),
        Case("encoder", "junk-safetensors", checkpoint("junk.safetensors", b"\xff" * 64)),
        Case("encoder", "checkpoint-folder", checkpoint("dir.pt", None)),
        Case("encoder", "empty-bin", checkpoint("empty.bin", b"")),
    ]


def compare_cases() -> list[Case]:
    """Malformed results.json given to clipclique-loc compare."""

    def results(change: Callable[[dict], object] | bytes | None) -> Callable:
        def make(space, case_dir):
            path = case_dir / "results.json"
            if change is None:
                path.mkdir()
                (path / "results.json").mkdir()
            elif isinstance(change, bytes):
                path.write_bytes(change)
            else:
                document = json.loads((space.loc / "results.json").read_text())
                path.write_text(json.dumps(change(document)))
            return loc_app, ["compare", str(path)], "results.json"

        return make

    def without(*keys: str) -> Callable[[dict], dict]:
        def change(document: dict) -> dict:
            part = document
            for key in keys[:-1]:
                part = part[key]
            del part[keys[-1]]
            return document

        return change

    def setting(value: object, *keys: str) -> Callable[[dict], dict]:
        def change(document: dict) -> dict:
            part = document
            for key in keys[:-1]:
                part = part[key]
            part[keys[-1]] = value
            return document

        return change

    cases = {
        "a-list": lambda d: [d],
        "no-run": without("run"),
        "no-summary": without("summary"),
        "run-a-string": setting("x", "run"),
        "no-sequence": without("run", "sequence"),
        "sequence-a-number": setting(3, "run", "sequence"),
        "detector-a-string": setting("gt", "run", "detector"),
        "notes-a-string": setting("note", "run", "notes"),
        "success-a-string": setting("high", "summary", "success@1"),
        "no-stage-medians": without("summary", "stage_ms_median"),
        "latin1": b'{"format": "' + LATIN1 + b'"}',
        "deep": _deep_json().encode(),
        "empty": b"",
        "folder": None,
    }
    return [Case("compare", name, results(change)) for name, change in cases.items()]


def name_cases() -> list[Case]:
    """Sequence names that lead out of the data root or nowhere."""

    def loc(name: str) -> Callable:
        return lambda space, case_dir: (loc_app, space.loc_args(sequence=name), name)

    def build(name: str) -> Callable:
        return lambda space, case_dir: (map_app, space.map_args(name), name)

    names = ("rgbd_dataset_x/../../../elsewhere", "rgbd_dataset_freiburg1_desk/../../demo/demo", "/", "no_such_scene")
    return [Case("names", f"loc-{n}", loc(n)) for n in names] + [Case("names", f"map-{n}", build(n)) for n in names]


def align_cases() -> list[Case]:
    """The damaged and hostile map files of `map_cases`, given to clipclique-loc align as MAP_A (and a few as MAP_B)."""

    def align(case: Case, role: str) -> Callable:
        def make(space: Workspace, case_dir: Path):
            _, args, named = case.make(space, case_dir)
            bad = args[args.index("--map") + 1]
            pair = [bad, str(space.map)] if role == "query" else [str(space.map), bad]
            return loc_app, ["align", *pair, "--out", str(space.loc / "align")], named

        return make

    cases = map_cases()
    return ([Case("align", f"{case.name}-as-query", align(case, "query")) for case in cases]
            + [Case("align", f"{case.name}-as-map", align(case, "map")) for case in cases[:6]])


def odometry_cases() -> list[Case]:
    """Broken --odometry trajectory files for clipclique-loc run --window."""
    good = "0 0 0 0 0 0 0 1\n1 0.1 0 0 0 0 0 1\n2 0.2 0 0 0 0 0 1\n3 0.3 0 0 0 0 0 1\n"

    def odometry(write: Callable[[Path], None]) -> Callable:
        def make(space: Workspace, case_dir: Path):
            path = case_dir / "vo.tum"
            path.write_text(good)
            write(path)
            return loc_app, space.loc_args("--window", "2", "--odometry", str(path)), "vo.tum"

        return make

    return [
        Case("odometry", "nan", odometry(lambda p: _insert(p, b"1.5 nan 0 0 0 0 0 1\n"))),
        Case("odometry", "seven-columns", odometry(lambda p: _insert(p, b"1.5 0 0 0 0 0 1\n"))),
        Case("odometry", "zero-quaternion", odometry(lambda p: _insert(p, b"1.5 0 0 0 0 0 0 0\n"))),
        Case("odometry", "latin1", odometry(lambda p: _insert(p, b"# " + LATIN1 + b"\n"))),
        Case("odometry", "utf16", odometry(lambda p: p.write_bytes(p.read_text().encode("utf-16")))),
        Case("odometry", "folder", odometry(_replace_dir)),
        Case("odometry", "missing", odometry(lambda p: p.unlink())),
        Case("odometry", "no-matching-time", odometry(lambda p: p.write_text("1700000000 0 0 0 0 0 0 1\n"))),
    ]



def import_cases() -> list[Case]:
    """Another system's map given to clipclique-map import: every reader refuses it in one line naming the file."""
    q = " ".join(f"{v:.8f}" for v in (np.diag([0.09, 0.01, 0.04, -1.0]) + np.outer([0, 0, 0, 0], [0] * 4)).T.ravel())
    skew = " ".join(f"{v:.8f}" for v in np.array([[0.09, 0.5, 0, 0], [0, 0.01, 0, 0], [0, 0, 0.04, 0],
                                                  [0, 0, 0, -1]]).T.ravel())
    good_node = {"id": 5, "translation": [1, 2, 3], "orientation": [1, 0, 0, 0], "radii": [0.1, 0.2, 0.3],
                 "baseline_label": {"41.0": [1.0, [0, 0, 0]]}}
    good_landmark = {"id": 1, "class": "cup", "center": [0, 0, 1], "semi_axes": [0.1, 0.1, 0.1],
                     "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}

    def landmarks(**change) -> bytes:
        return json.dumps({"format": "clipclique-landmarks", "version": 1,
                           "landmarks": [good_landmark | change]}).encode()

    def imported(name: str, data: bytes, *extra: str, files: dict[str, bytes] | None = None, named: str | None = None):
        def make(space: Workspace, case_dir: Path):
            for other, content in (files or {}).items():
                (case_dir / other).write_bytes(content)
            (case_dir / name).write_bytes(data)
            return (map_app, ["import", str(case_dir / name), "--out", str(space.map), "--encoder", "none", *extra],
                    named or name)

        return make

    def osmap(objects: bytes, key: str = "objectsFile") -> Callable:
        return imported("map_x.yaml", f'%YAML:1.0\n{key}: "map_x.objects"\n'.encode(), files={"map_x.objects": objects},
                        named="map_x.objects")

    makers = {
        "text-fields": imported("map_objects_x.txt", b"1 41 1 2 3\n"),
        "text-words": imported("map_objects_x.txt", ("1 41 " + " ".join(["one"] * 16) + "\n").encode()),
        "text-category-99": imported("map_objects_x.txt", f"1 99 {q}\n".encode()),
        "text-asymmetric": imported("map_objects_x.txt", f"1 41 {skew}\n".encode()),
        "text-not-utf8": imported("map_objects_x.txt", f"1 41 {q}\n".encode() + LATIN1),
        "text-nul": imported("map_objects_x.txt", f"1 41 {q}\n\0".encode()),
        "text-empty": imported("map_objects_x.txt", b""),
        "text-1e300": imported("map_objects_x.txt", ("1 41 " + q.replace("0.00000000", "1e300", 1) + "\n").encode()),
        "osmap-truncated": osmap(b"\x0a\xff\x01"),
        "osmap-wire-type-7": osmap(b"\x0f"),
        "osmap-15-floats": osmap(b"\x0a\x42\x0a\x40\x0a\x3c" + bytes(60)),
        "osmap-varint-runaway": osmap(b"\x08" + b"\xff" * 20),
        "osmap-no-objects-key": imported("map_x.yaml", b"%YAML:1.0\nkeyframesFile: x\n"),
        "osmap-missing-file": imported("map_x.yaml", b'%YAML:1.0\nobjectsFile: "gone.objects"\n', named="gone.objects"),
        "osmap-escaping-path": imported("map_x.yaml", b'%YAML:1.0\nobjectsFile: "../../maps/demo.map.npz"\n'),
        "msgloc-not-json": imported("m.json", b"{nodes"),
        "msgloc-deep": imported("m.json", _deep_json().encode()),
        "msgloc-nodes-not-list": imported("m.json", b'{"nodes": 3}'),
        "msgloc-quaternion": imported("m.json",
                                      json.dumps({"nodes": [good_node | {"orientation": [3, 0, 0, 0]}]}).encode()),
        "msgloc-id-text": imported("m.json", json.dumps({"nodes": [good_node | {"id": "x"}]}).encode()),
        "msgloc-no-label": imported("m.json",
                                    json.dumps({"nodes": [{k: v for k, v in good_node.items()
                                                           if k != "baseline_label"}]}).encode()),
        "json-version-9": imported("l.json", json.dumps({"format": "clipclique-landmarks", "version": 9}).encode()),
        "json-rotation": imported("l.json", landmarks(rotation=[[2, 0, 0], [0, 1, 0], [0, 0, 1]])),
        "json-class-control": imported("l.json", landmarks(**{"class": "c\x1bup"})),
        "json-distribution": imported("l.json", landmarks(class_distribution={"cup": 0.4})),
        "voom-without-classes": osmap(b"\x0a\x47\x0a\x42\x0a\x40"
                                      + np.diag([0.09, 0.01, 0.04, -1.0]).astype("<f4").tobytes()
                                      + b"\x10\x07", key="ObjectsFile"),
    }
    cases = [Case("import", name, make) for name, make in makers.items()]

    def aligned(name: str, trajectory: bytes) -> Callable:
        def make(space: Workspace, case_dir: Path):
            (case_dir / name).write_bytes(trajectory)
            app, args, _ = imported("map_objects_x.txt", f"1 41 {q}\n".encode())(space, case_dir)
            return app, [*args, "--groundtruth", str(space.data / "demo" / "demo_tum" / "groundtruth.txt"),
                         "--trajectory", str(case_dir / name)], name

        return make

    cases += [Case("import", "trajectory-bad-line", aligned("kf.txt", b"1.0 0 0 0 0 0 0\n")),
              Case("import", "trajectory-no-match", aligned("kf.txt", b"5.0 0 0 0 0 0 0 1\n" * 12))]

    def bad_csv(space: Workspace, case_dir: Path):
        (case_dir / "objects.csv").write_text("id,name\n1,cup\n")
        app, args, _ = imported("map_objects_x.txt", f"1 41 {q}\n".encode(), "--objects",
                                str(case_dir / "objects.csv"))(space, case_dir)
        return app, args, "objects.csv"

    cases.append(Case("import", "objects-csv-header", bad_csv))
    return cases


def label_cases() -> list[Case]:
    """A hostile names file given as --labels FILE to import (an LVIS-like list): one line naming the file."""
    q = " ".join(f"{v:.8f}" for v in np.diag([0.09, 0.01, 0.04, -1.0]).T.ravel())

    def labelled(text: bytes) -> Callable:
        def make(space: Workspace, case_dir: Path):
            (case_dir / "lvis.txt").write_bytes(text)
            (case_dir / "map_objects_x.txt").write_text(f"1 41 {q}\n")
            return map_app, ["import", str(case_dir / "map_objects_x.txt"), "--labels", str(case_dir / "lvis.txt"),
                             "--out", str(case_dir / "x.map.npz"), "--encoder", "none", "--no-rrd"], "lvis.txt"

        return make

    names = [f"class {i}" for i in range(60)]
    makers = {
        "missing-line": labelled("\n".join(names[:41]).encode()),  # id 41 is past the last line
        "blank-line": labelled("\n".join(names[:5] + [""] + names[5:]).encode()),
        "not-utf8": labelled("\n".join(names).encode() + LATIN1),
        "million-lines": labelled(b"x\n" * 1_000_000),
        "control": labelled("\n".join(names[:3] + ["c\x1bup"] + names[3:]).encode()),
        "empty": labelled(b""),
    }
    return [Case("labels", name, make) for name, make in makers.items()]


def detection_cases() -> list[Case]:
    """A detection file given to clipclique-loc run --detector file:: each reader refuses it in one line naming it."""
    good = {"category_id": 41, "detection_score": 0.5, "bbox": [10, 10, 40, 40]}
    rle = {"size": [120, 160], "counts": "PPYo1"}
    coco = {"image_id": 0, "category_id": 47, "bbox": [10, 10, 30, 30], "score": 0.5, "segmentation": rle}

    def frames(*detections: dict) -> bytes:
        return json.dumps([{"file_name": "rgb/x.png", "detections": list(detections)}]).encode()

    def given(name: str, data: bytes, images: bytes | None = None, named: str | None = None):
        def make(space: Workspace, case_dir: Path):
            (case_dir / name).write_bytes(data)
            if images is not None:
                (case_dir / "images.json").write_bytes(images)
            return loc_app, space.loc_args("--detector", f"file:{case_dir / name}"), named or name

        return make

    image_list = json.dumps({"images": [{"id": 0, "file_name": "0.png"}]}).encode()
    makers = {
        "not-json": given("d.json", b"[{"),
        "deep": given("d.json", _deep_json().encode()),
        "not-a-list": given("d.json", b'{"file_name": "x"}'),
        "no-detections": given("d.json", b'[{"file_name": "x.png"}]'),
        "category-80": given("d.json", frames(good | {"category_id": 80})),
        "score-nan": given("d.json", frames(good | {"detection_score": float("nan")})),
        "bbox-inverted": given("d.json", frames(good | {"bbox": [40, 40, 10, 10]})),
        "bbox-text": given("d.json", frames(good | {"bbox": "10 10 40 40"})),
        "ellipse-short": given("d.json", frames(good | {"ellipse": [1, 2, 3]})),
        "not-utf8": given("d.json", frames(good) + LATIN1),
        "other-sequence": given("d.json", frames(good)),  # well formed, but names none of the demo's frames
        "coco-no-image-list": given("r.json", json.dumps([coco]).encode()),
        "coco-image-unknown": given("r.json", json.dumps([coco | {"image_id": 5}]).encode(), image_list),
        "coco-category-0": given("r.json", json.dumps([coco | {"category_id": 0}]).encode(), image_list),
        "coco-bbox-negative": given("r.json", json.dumps([coco | {"bbox": [10, 10, -5, 30]}]).encode(), image_list),
        "coco-rle-corrupt": given("r.json",
                                  json.dumps([coco
                                              | {"segmentation": {"size": [120, 160],
                                                                  "counts": "\u00ff\u00fe"}}]).encode(), image_list),
        "coco-rle-short": given("r.json",
                                json.dumps([coco | {"segmentation": {"size": [120, 160], "counts": [5, 5]}}]).encode(),
                                image_list),
        "coco-image-list-broken": given("r.json", json.dumps([coco]).encode(), b'{"images": [{"id": "zero"}]}',
                                        named="images.json"),
        "coco-mask-wrong-size": given("r.json",
                                      json.dumps([coco
                                                  | {"segmentation": {"size": [10, 10], "counts": [100]}}]).encode(),
                                      image_list),
    }
    return [Case("detections", name, make) for name, make in makers.items()]


CASES = (map_cases() + align_cases() + odometry_cases() + config_cases() + tum_cases() + annotate_cases()
         + scannet_cases() + frame_cases() + output_cases() + encoder_cases() + compare_cases() + name_cases()
         + import_cases() + label_cases() + detection_cases())


def test_the_suite_is_large_and_covers_every_family():
    assert len(CASES) >= 100
    assert len({str(case) for case in CASES}) == len(CASES)
    assert {case.family for case in CASES} >= {"map", "config", "tum-text", "tum-data", "tum-image", "scannet",
                                               "frames",
                                               "outputs", "encoder", "compare", "names", "import",
                                               "detections", "labels", "annotate",
                                               "align", "odometry"}


@pytest.mark.parametrize("case", CASES, ids=str)
def test_hostile_input_is_one_line_exit_2_and_loses_nothing(case: Case, workspace: Workspace, tmp_path: Path):
    before = snapshot(workspace.root / "maps", workspace.loc)
    app, args, named = case.make(workspace, tmp_path)
    result = RUNNER.invoke(app, args)
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2, f"exit {result.exit_code}: {result.output[-2000:]} {result.exception!r}"
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    assert len(lines) == 1 and "error" in lines[0], result.output
    assert named in lines[0], f"{named!r} not named in: {lines[0]}"
    assert leftovers(workspace.root) == [] and leftovers(tmp_path) == []
    assert snapshot(workspace.root / "maps", workspace.loc) == before
    assert not PWNED.exists()  # no pickle was ever run


def test_a_label_file_naming_one_class_twice_imports_with_a_note(tmp_path: Path):
    """Two ids with one name are accepted (both ids mean that class), with a note naming the file and the ids."""
    q = " ".join(f"{v:.8f}" for v in np.diag([0.09, 0.01, 0.04, -1.0]).T.ravel())
    names = [f"class {i}" for i in range(60)]
    names[50] = "class 41"
    (tmp_path / "lvis.txt").write_text("\n".join(names) + "\n")
    (tmp_path / "map_objects_x.txt").write_text(f"1 41 {q}\n2 50 {q.replace('-1.0', '-2.0')}\n")
    result = RUNNER.invoke(map_app, ["import", str(tmp_path / "map_objects_x.txt"), "--labels",
                                     str(tmp_path / "lvis.txt"), "--out", str(tmp_path / "x.map.npz"), "--encoder",
                                     "none", "--no-rrd"])
    assert result.exit_code == 0, result.output
    assert f"{tmp_path / 'lvis.txt'}: 1 names given to several ids (first 'class 41': ids 41, 50)" in " ".join(
        result.output.split())
    from clipclique.io.mapfile import load_map

    imported = load_map(tmp_path / "x.map.npz")
    assert imported.class_names == ["class 41"] and imported.class_ids.tolist() == [0, 0]
