"""ScanNet v2 scene folders, as ScanNet ships them and its SensReader exports them.

Read from `scans/<scene>/`:
- `<scene>_vh_clean_2.labels.ply`: mesh vertices (x, y, z, colour, ushort `label` = ScanNet label id);
- `<scene>_vh_clean_2.0.010000.segs.json`: `segIndices`, the segment of every vertex;
- `<scene>.aggregation.json`: `segGroups`, one per object (objectId, raw category `label`, segments);
- SensReader output: `color/N.jpg`, `depth/N.png` (uint16 mm), `pose/N.txt` (4x4 camera-to-world,
  `-inf` where tracking failed: those frames are skipped), `intrinsic/intrinsic_depth.txt`;
- `instance-filt/N.png` when `<scene>_2d-instance-filt.zip` is unzipped (8-bit, objectId + 1);
  without them, frames get the labelled mesh ray-cast into the view, kept where depth agrees;
- `scannetv2-labels.combined.tsv` in the scene folder or up to two folders above it: raw
  categories become NYU40 classes (`nyu40class`); without it the raw categories are the classes;
- `<scene>_descriptions.json` (ours, optional): `{"<objectId>": "a red office chair"}`.

Object ids are `objectId + 1` everywhere (instances, frames, classes) so that 0 means "none",
as in the instance images. Colour images are resampled to the depth image's size so that the
depth intrinsics serve both.
"""

from __future__ import annotations

import csv
import io
from functools import cached_property
from pathlib import Path

import numpy as np

from clipclique.datasets.base import (
    Instance,
    Sequence,
    description_template,
    intrinsics_for,
    is_demo,
    is_structure,
    read_depth,
    read_image,
    read_instance_ids,
    read_json,
    resize_rgb,
)
from clipclique.errors import DatasetError
from clipclique.io import safeio
from clipclique.perception.raycast import MeshRaycaster
from clipclique.types import Frame, Pose

LABELS_TSV = "scannetv2-labels.combined.tsv"
DEPTH_FACTOR = 1000.0
MAX_OBJECT_ID = 2**31 - 1  # object ids are int32 in frames
TRIANGLES = {"face": {"vertex_indices": 3, "vertex_index": 3}}  # plyfile maps faces of known length in one go


class ScanNetScene(Sequence):
    kind = "scannet"
    default_detector = "gt"

    @staticmethod
    def recognizes(folder: Path) -> bool:
        return any(folder.glob("*_vh_clean_2.labels.ply"))

    def __init__(self, folder: Path):
        self.root = Path(folder)
        self.name = self.root.name
        self.synthetic = is_demo(self.root)
        self.mesh_path = self.root / f"{self.name}_vh_clean_2.labels.ply"
        self.segs_path = self.root / f"{self.name}_vh_clean_2.0.010000.segs.json"
        self.aggregation_path = self.root / f"{self.name}.aggregation.json"
        missing = [p.name for p in (self.mesh_path, self.segs_path, self.aggregation_path) if not p.is_file()]
        if missing:
            raise DatasetError(f"{self.root}: ScanNet scene is missing {', '.join(missing)}")
        self.frame_numbers, self.poses = self._read_poses()
        self.intrinsics = self._read_intrinsics() if len(self.frame_numbers) else None

    # ---- frames -------------------------------------------------------------------------------

    def _read_poses(self) -> tuple[list[int], list[Pose]]:
        """Frames with a finite pose, in frame-number order (none when frames are not exported)."""
        pose_dir = self.root / "pose"
        files = (sorted(pose_dir.glob("*.txt"), key=lambda p: int(p.stem) if p.stem.isdigit() else -1)
                 if pose_dir.is_dir() else [])
        numbers, poses = [], []
        for path in files:
            if not path.stem.isdigit():
                continue
            matrix = read_matrix(path, "pose")
            if matrix.shape != (4, 4):
                raise DatasetError(f"{path}: expected a 4x4 pose matrix, got shape {matrix.shape}")
            if np.isfinite(matrix).all():  # -inf marks a frame where tracking failed
                check_rigid(matrix, path)
                numbers.append(int(path.stem))
                poses.append(Pose.from_matrix(matrix))
        return numbers, poses

    def _read_intrinsics(self) -> np.ndarray:
        path = self.root / "intrinsic" / "intrinsic_depth.txt"
        matrix = read_matrix(path, "depth intrinsics")
        if matrix.shape not in ((4, 4), (3, 3)) or not np.isfinite(matrix).all():
            raise DatasetError(f"{path}: expected a finite 4x4 (or 3x3) matrix, got shape {matrix.shape}")
        if min(matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2]) <= 0:
            raise DatasetError(f"{path}: focal lengths and principal point must be positive")
        return matrix[:3, :3].copy()

    def __len__(self) -> int:
        return len(self.frame_numbers)

    def trajectory(self) -> tuple[np.ndarray, list[Pose | None]]:
        return np.array(self.frame_numbers, np.float64), list(self.poses)

    def frame_name(self, i: int) -> str:
        return str(self.frame_numbers[i])

    def __getitem__(self, i: int) -> Frame:
        i = self._check_index(i)
        n = self.frame_numbers[i]
        depth_path = self.root / "depth" / f"{n}.png"
        depth = read_depth(depth_path, DEPTH_FACTOR)
        intrinsics = intrinsics_for(self.intrinsics, depth.shape, depth_path,
                                    str(self.root / "intrinsic" / "intrinsic_depth.txt"))
        rgb = resize_rgb(read_image(self.root / "color" / f"{n}.jpg", "RGB"), depth.shape)
        instance_path = self.root / "instance-filt" / f"{n}.png"
        if instance_path.exists():
            labels = read_instance_ids(instance_path)
            if labels.shape != depth.shape:
                from PIL import Image

                labels = np.asarray(Image.fromarray(labels).resize(depth.shape[::-1], Image.NEAREST))
            instances = labels.astype(np.int32)
        else:
            instances = self.project_instances(self.poses[i], depth, intrinsics)
        return Frame(i, float(n), rgb, depth, intrinsics, self.poses[i], instances, name=str(n))

    def project_instances(self, pose: Pose, depth: np.ndarray, intrinsics: np.ndarray,
                          tolerance: float = 0.1) -> np.ndarray:
        """Object ids of the labelled mesh rendered into a frame, kept where the measured depth agrees.

        Stands in for the 2D instance images when `<scene>_2d-instance-filt.zip` is not unzipped.
        """
        raycaster, face_ids = self._projector
        render = raycaster.render(intrinsics, pose, depth.shape)
        agrees = (render.faces >= 0) & (depth > 0) & (np.abs(render.depth - depth) < tolerance)
        return np.where(agrees, face_ids[np.maximum(render.faces, 0)], 0).astype(np.int32)

    # ---- objects ------------------------------------------------------------------------------

    @cached_property
    def _ply(self):
        from plyfile import PlyData, PlyElementParseError

        try:
            try:  # triangles read as one array: 0.05 s instead of 2.7 s row by row for the demo's mesh
                return PlyData.read(str(self.mesh_path), known_list_len=TRIANGLES)
            except PlyElementParseError:  # faces that are not all triangles (or a damaged file): row by row
                return PlyData.read(str(self.mesh_path))
        except Exception as error:  # plyfile raises several types for a damaged file
            raise DatasetError(f"{self.mesh_path}: unreadable PLY mesh ({error})") from None

    @cached_property
    def _vertices(self) -> np.ndarray:
        """The labelled mesh's vertex table (x, y, z, red, green, blue, label, ...)."""
        vertex = self._ply["vertex"].data
        missing = {"x", "y", "z", "label"} - set(vertex.dtype.names or ())
        if missing:
            raise DatasetError(f"{self.mesh_path}: vertex property {', '.join(sorted(missing))} missing")
        return vertex

    @cached_property
    def _xyz(self) -> np.ndarray:
        """(V, 3) float64 mesh vertex positions."""
        return np.column_stack([self._vertices[axis] for axis in "xyz"]).astype(np.float64)

    @cached_property
    def _class_of(self) -> dict[str, str]:
        """Raw category -> class: NYU40 names from the label table when one is found, else identity."""
        for folder in (self.root, self.root.parent, self.root.parent.parent):
            if (folder / LABELS_TSV).exists():
                return read_label_table(folder / LABELS_TSV)
        return {}

    @cached_property
    def _grouping(self) -> tuple[list[int], list[str], np.ndarray]:
        """Instance ids (objectId + 1) and raw categories of the segGroups, and each vertex's group index."""
        segments = integer_array(read_json(self.segs_path).get("segIndices"), f"{self.segs_path}: segIndices")
        if len(segments) != len(self._vertices):
            raise DatasetError(
                f"{self.segs_path}: {len(segments)} segIndices for {len(self._vertices)} vertices of "
                f"{self.mesh_path.name}"
            )
        groups = read_json(self.aggregation_path).get("segGroups")
        if not isinstance(groups, list) or not all(isinstance(g, dict) for g in groups):
            raise DatasetError(f"{self.aggregation_path}: no segGroups list of objects")
        where = f"{self.aggregation_path}: segGroup"
        try:
            ids = [int(integer_array([g["objectId"]], f"{where} objectId")[0]) + 1 for g in groups]
            labels = [safeio.check_text(g["label"], f"{where} label") for g in groups]
            members = [integer_array(g["segments"], f"{where} segments") for g in groups]
        except KeyError as error:
            raise DatasetError(f"{where} without {error}") from None
        if ids and not 1 <= min(ids) <= max(ids) <= MAX_OBJECT_ID:
            raise DatasetError(f"{where} objectId outside 0..{MAX_OBJECT_ID - 1}")
        if (duplicate := _first_duplicate(ids)) is not None:
            raise DatasetError(f"{self.aggregation_path}: objectId {duplicate - 1} appears in more than one segGroup")
        return ids, labels, vertex_owner(segments, members)

    @cached_property
    def _objects(self) -> list[tuple[int, str, str, np.ndarray]]:
        """(instance id, raw category, class, vertex indices) per aggregation segGroup."""
        ids, labels, owner = self._grouping
        order = np.argsort(owner, kind="stable")
        splits = np.searchsorted(owner[order], np.arange(len(ids) + 1))
        return [
            (object_id, label, self._class_of.get(label, label), order[splits[k] : splits[k + 1]])
            for k, (object_id, label) in enumerate(zip(ids, labels))
        ]

    @cached_property
    def _projector(self) -> tuple[MeshRaycaster, np.ndarray]:
        """Ray caster of the labelled mesh and the instance id of each face (by its first vertex)."""
        if "face" not in self._ply:
            raise DatasetError(f"{self.mesh_path}: no faces, cannot project objects into frames "
                               "(unzip the 2D instances)")
        corners = self._ply["face"].data["vertex_indices"]  # (F, 3) when read as triangles, else one array per face
        faces = (np.vstack(corners) if corners.dtype == object else corners).astype(np.int32)
        ids, _, owner = self._grouping
        vertex_ids = np.append(ids, 0)[owner]  # owner == len(ids): in no group
        return MeshRaycaster(self._xyz, faces), vertex_ids[faces[:, 0]]

    @cached_property
    def _descriptions(self) -> dict[int, str]:
        path = self.root / f"{self.name}_descriptions.json"
        if not path.exists():
            return {}
        try:
            return {int(key) + 1: safeio.check_text(text, f"{path}: description")
                    for key, text in read_json(path).items()}
        except ValueError:
            raise DatasetError(f'{path}: keys must be ScanNet objectIds, e.g. {{"0": "a red office chair"}}') from None

    def instances(self) -> list[Instance]:
        return [
            Instance(object_id, class_name, self._descriptions.get(object_id, description_template(class_name)),
                     self._xyz[vertices])
            for object_id, _, class_name, vertices in self._objects
        ]

    def object_classes(self) -> dict[int, str]:
        return {object_id: name for object_id, _, name, _ in self._objects if not is_structure(name)}

    def descriptions(self) -> dict[int, str]:
        return {object_id: self._descriptions.get(object_id, description_template(name))
                for object_id, name in self.object_classes().items()}

    def scene_cloud(self) -> tuple[np.ndarray, np.ndarray]:
        vertex = self._vertices
        names = vertex.dtype.names
        rgb = (np.column_stack([vertex[c] for c in ("red", "green", "blue")]) if "red" in names
               else np.full((len(vertex), 3), 180))
        return self._xyz, rgb.astype(np.uint8)


def vertex_owner(segments: np.ndarray, members: list[np.ndarray]) -> np.ndarray:
    """Index of the group owning each vertex's segment, or len(members) when none does."""
    owner = np.full(len(segments), len(members), dtype=np.int64)
    if not members:
        return owner
    member_segments = np.concatenate(members)
    member_group = np.repeat(np.arange(len(members)), [len(m) for m in members])
    order = np.argsort(member_segments, kind="stable")
    sorted_segments = member_segments[order]
    pos = np.clip(np.searchsorted(sorted_segments, segments), 0, len(sorted_segments) - 1)
    found = sorted_segments[pos] == segments
    owner[found] = member_group[order][pos[found]]
    return owner


def read_label_table(path: Path) -> dict[str, str]:
    """raw_category -> nyu40class from ScanNet's `scannetv2-labels.combined.tsv`."""
    text = safeio.read_text(path, "label table", DatasetError)
    reader = csv.DictReader(io.StringIO(text, newline=""), delimiter="\t")
    missing = {"raw_category", "nyu40class"} - set(reader.fieldnames or ())
    if missing:
        raise DatasetError(f"{path}: column {', '.join(sorted(missing))} missing; is this the ScanNet label table?")
    return {row["raw_category"]: row["nyu40class"] for row in reader if row["raw_category"] and row["nyu40class"]}


def read_matrix(path: Path, what: str) -> np.ndarray:
    """A whitespace-separated matrix of numbers in a UTF-8 text file."""
    text = safeio.read_text(path, what, DatasetError)
    try:
        rows = [[float(v) for v in line.split()] for line in text.splitlines() if line.strip()]
        return np.array(rows, dtype=np.float64)
    except ValueError as error:  # a non-number, or rows of different lengths
        raise DatasetError(f"{path}: not a {what} matrix of numbers ({error})") from None


def check_rigid(matrix: np.ndarray, path: Path, tolerance: float = 1e-3) -> None:
    """A camera pose must be a rotation (orthonormal, det +1) and translation with a 0 0 0 1 last row."""
    rotation = matrix[:3, :3]
    if (
        not np.allclose(matrix[3], [0, 0, 0, 1], atol=tolerance)
        or not np.allclose(rotation.T @ rotation, np.eye(3), atol=tolerance)
        or np.linalg.det(rotation) < 0
    ):
        raise DatasetError(f"{path}: not a rigid camera pose (the rotation is not orthonormal with det +1, or the last "
                           "row is not 0 0 0 1)")


def integer_array(values: object, where: str) -> np.ndarray:
    """A flat list of JSON integers as int64; floats, strings, nesting and out-of-range values refused."""
    if not isinstance(values, list) or not all(type(v) is int for v in values):
        raise DatasetError(f"{where} must be a flat list of integers")
    try:
        return np.array(values, dtype=np.int64)
    except OverflowError:
        raise DatasetError(f"{where} holds an integer beyond 64 bits") from None


def _first_duplicate(values: list[int]) -> int | None:
    seen: set[int] = set()
    for value in values:
        if value in seen:
            return value
        seen.add(value)
    return None
