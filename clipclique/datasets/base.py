"""What every dataset reader provides, and the small image readers they share."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clipclique.errors import DatasetError
from clipclique.io import safeio
from clipclique.types import Frame, Pose

# Room structure, not landmarks: left out of maps and ground-truth detections.
STRUCTURE_CLASSES = frozenset({"wall", "floor", "ceiling"})


def is_structure(class_name: str) -> bool:
    """True for room structure (wall, floor, ceiling; any case), which never becomes a landmark."""
    return class_name.strip().lower() in STRUCTURE_CLASSES


# Marker the demo generator writes last into each demo scene folder.
DEMO_MARKER = "clipclique_demo.json"


def description_template(class_name: str) -> str:
    """The description of an object whose dataset gives none (CLIP's usual prompt form)."""
    return f"a photo of a {class_name}"


@dataclass
class Instance:
    """One object of a scene: the input of map building."""

    instance_id: int  # dataset object id (ScanNet objectId + 1; TUM annotation id), never 0
    class_name: str
    description: str  # from the scene's descriptions, else description_template(class_name)
    points: np.ndarray  # (P, 3) world frame


class Sequence(ABC):
    """A scene or sequence of one dataset: frames in order plus its annotated objects."""

    name: str
    kind: str  # "scannet" | "tum" | "rosbag"
    root: Path
    synthetic: bool  # True for the generated demo scenes (their ground truth is exact)
    # the `--detector` its frames get unless asked (a generated scene's own comes from clipclique.sim)
    default_detector: str

    @staticmethod
    @abstractmethod
    def recognizes(folder: Path) -> bool:
        """Whether `folder` holds this dataset's files (how `open_folder` tells readers apart)."""

    @abstractmethod
    def __len__(self) -> int: ...

    @abstractmethod
    def __getitem__(self, i: int) -> Frame: ...

    @abstractmethod
    def instances(self) -> list[Instance]:
        """Every annotated object (structure included) with its world points."""

    @abstractmethod
    def object_classes(self) -> dict[int, str]:
        """Dataset object id -> class name of the objects that can be landmarks (no structure)."""

    @abstractmethod
    def descriptions(self) -> dict[int, str]:
        """Dataset object id -> description of the objects that can be landmarks (no structure)."""

    def missing_poses(self) -> str | None:
        """How many frames have no ground-truth pose and why, for the messages a user reads (a map built
        without them, a run that cannot be scored); None when every frame has one."""
        return None

    def notes(self) -> list[str]:
        """Facts about how the frames were read that a run's user must see (a bag's distortion ignored, ...)."""
        return []

    def scene_cloud(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(points (P, 3), colours (P, 3) uint8) of the whole scene for viewers, None if unknown."""
        return None

    def frame_name(self, i: int) -> str:
        """Frame `i`'s name (what a detection file names it by); readers that know it without decoding images
        say so cheaper."""
        return self[i].name

    def trajectory(self) -> tuple[np.ndarray, list[Pose | None]]:
        """(timestamps (F,), ground-truth camera-to-world pose or None) of every frame; readers that know them
        without decoding images say so cheaper."""
        frames = [self[i] for i in range(len(self))]
        return np.array([frame.timestamp for frame in frames]), [frame.pose for frame in frames]

    def __iter__(self) -> Iterator[Frame]:
        return (self[i] for i in range(len(self)))

    def _check_index(self, i: int) -> int:
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} out of range for {self.name} ({len(self)} frames)")
        return i % len(self)


def is_demo(folder: Path) -> bool:
    """True for a folder the demo generator wrote (its marker file is there)."""
    return (folder / DEMO_MARKER).is_file()


def read_json(path: Path) -> dict:
    """A JSON file holding an object, with a DatasetError naming the file otherwise."""
    data = safeio.read_json(path, error=DatasetError)
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a JSON object {{...}}, got a {type(data).__name__}")
    return data


def read_image(path: Path, mode: str | None = None) -> np.ndarray:
    """An image file as an array, size-checked before decoding; a DatasetError naming the file when unreadable."""
    return safeio.read_image(path, mode, error=DatasetError)


def read_depth(path: Path, factor: float) -> np.ndarray:
    """A 16-bit depth PNG as float32 metres (0 stays 0 = invalid); 8-bit depth is refused, its unit unknown."""
    raw = safeio.read_single_channel(path, "depth", error=DatasetError)
    if raw.dtype.itemsize < 2:
        raise DatasetError(f"{path}: 8-bit depth image; depth must be 16-bit (1/{factor:g} m per unit)")
    return raw.astype(np.float32) / np.float32(factor)


def read_instance_ids(path: Path) -> np.ndarray:
    """A single-channel instance image (8- or 16-bit object ids) as int32."""
    return safeio.read_single_channel(path, "instance", error=DatasetError).astype(np.int32)


def intrinsics_for(intrinsics: np.ndarray, shape: tuple[int, int], path: Path,
                   source: str = "the depth intrinsics") -> np.ndarray:
    """The depth intrinsics (read from `source`) rescaled to the depth image `path` of `shape` (H, W).

    The principal point lies near the image centre, so a matrix whose (cx, cy) sits at twice
    (or half, ...) the centre of this image was calibrated at that image size: scale it by the
    power of two that fits. A principal point that fits no such size is refused.
    """
    height, width = shape
    ratios = np.array([width / (2 * intrinsics[0, 2]), height / (2 * intrinsics[1, 2])])
    scale = 2.0 ** np.round(np.log2(ratios[0]))
    if not np.all(np.abs(ratios / scale - 1) < 0.2):
        raise DatasetError(
            f"{path}: depth image {width} x {height} does not fit {source} (principal point "
            f"{intrinsics[0, 2]:g}, {intrinsics[1, 2]:g}); the intrinsics belong to another camera"
        )
    if scale == 1:
        return intrinsics
    scaled = intrinsics.copy()
    scaled[:2] *= scale
    return scaled


def resize_rgb(rgb: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """RGB resampled to the depth image's (H, W) so that one intrinsics matrix serves both."""
    from PIL import Image

    if rgb.shape[:2] == shape:
        return rgb
    return np.asarray(Image.fromarray(rgb).resize((shape[1], shape[0]), Image.BILINEAR))
