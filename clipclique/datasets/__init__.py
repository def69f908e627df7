"""Dataset readers: one module per dataset, a registry of them by name (`READERS`), one entry point
(`open_sequence`) by scene name or folder. Readers only read: a generated scene (clipclique.sim) is
an ordinary ScanNet or TUM folder, generated before it is opened.

Every reader yields `Frame`s (depth in metres, camera-to-world ground-truth pose, per-pixel
dataset object ids where the dataset has them) and the scene's object `Instance`s that
`clipclique-map` turns into landmarks, and says which detector its frames get by default.
Adding a dataset means adding one module and one line in `READERS`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from clipclique.datasets.base import STRUCTURE_CLASSES, Instance, Sequence, description_template, is_structure
from clipclique.datasets.rosbag import BagOptions, BagSequence, is_bag
from clipclique.datasets.scannet import ScanNetScene
from clipclique.datasets.tum import TumSequence
from clipclique.errors import DatasetError

__all__ = [
    "READERS",
    "BagOptions",
    "STRUCTURE_CLASSES",
    "Instance",
    "Sequence",
    "description_template",
    "is_bag",
    "is_structure",
    "open_folder",
    "open_sequence",
    "resolve_data_root",
    "scene_name",
]

# Reader by dataset name (`Sequence.kind`), in the order `open_folder` tries them.
READERS: dict[str, type[Sequence]] = {"tum": TumSequence, "scannet": ScanNetScene, "rosbag": BagSequence}

DATA_ENV = "CLIPCLIQUE_DATA"
SCANNET_NAME = re.compile(r"^scene\d{4}_\d{2}$")
TUM_SHORT_NAMES = {
    "fr1": "rgbd_dataset_freiburg1_desk",
    "fr2": "rgbd_dataset_freiburg2_desk",
    "fr3": "rgbd_dataset_freiburg3_long_office_household",
}
SCANNET_URL = "http://www.scan-net.org (request access and accept its terms of use)"
TUM_URL = "https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download"


def resolve_data_root(cli_value: Path | None = None) -> Path:
    """--data-root, else $CLIPCLIQUE_DATA, else ./data."""
    if cli_value is not None:
        return Path(cli_value)
    return Path(os.environ.get(DATA_ENV) or "data")


def open_sequence(name: str, data_root: Path | None = None, bag: BagOptions | None = None) -> Sequence:
    """A scene or sequence by short name ("scene0002_00", "fr2", "fr3"), folder path or ROS bag (read with the
    `bag` options); never generates one (the generated scenes' names are resolved by
    `clipclique.resolve.open_scene`)."""
    if is_bag(Path(name)):
        return BagSequence(Path(os.path.abspath(name)), bag)
    root = resolve_data_root(data_root)
    if SCANNET_NAME.match(name):
        folder = root / "scannet" / "scans" / name
        if not folder.is_dir():
            raise DatasetError(
                f"ScanNet scene {name} not found: expected the folder {folder}/ holding "
                f"{name}_vh_clean_2.labels.ply, {name}.aggregation.json, {name}_vh_clean_2.0.010000.segs.json "
                f"and the SensReader export (color/ depth/ pose/ intrinsic/). Get ScanNet from {SCANNET_URL}; "
                f"point --data-root or ${DATA_ENV} at the folder that holds scannet/scans/."
            )
        return READERS["scannet"](folder)
    if name in TUM_SHORT_NAMES or name.startswith("rgbd_dataset_"):
        folder = root / "tum" / TUM_SHORT_NAMES.get(name, _folder_name(name, root / "tum"))
        if not folder.is_dir():
            raise DatasetError(
                f"TUM RGB-D sequence {name} not found: expected the folder {folder}/ holding rgb/ depth/ "
                f"rgb.txt depth.txt groundtruth.txt (the .tgz from {TUM_URL}, extracted there); point "
                f"--data-root or ${DATA_ENV} at the folder that holds tum/."
            )
        return READERS["tum"](folder)
    if Path(name).is_dir():
        return open_folder(Path(os.path.abspath(name)))
    raise DatasetError(
        f"unknown scene {name!r}: use a ScanNet name (scene0002_00), fr1/fr2/fr3, a TUM folder name "
        f"(rgbd_dataset_freiburg2_desk), demo, demo_tum, the path of a scene folder, or a ROS bag (.bag, .mcap, .db3 "
        f"or a ROS 2 bag folder)"
    )


def scene_name(name: str) -> str:
    """The name output files of SCENE are named after: a dataset name (a short one resolved: `fr2` is
    rgbd_dataset_freiburg2_desk, so that one scene has one map whichever name is typed), else the name of the
    folder a path leads to (`seq/sub/..` is `seq`), so that outputs never land in `..`."""
    if name in TUM_SHORT_NAMES:
        return TUM_SHORT_NAMES[name]
    if name.startswith("rgbd_dataset_"):
        return _folder_name(name, Path("<data root>") / "tum")
    if is_bag(Path(name)):  # a bag file: its stem (rec.bag -> rec), as the reader names its sequence
        return Path(os.path.abspath(name)).stem if Path(name).is_file() else Path(os.path.abspath(name)).name
    folder = Path(os.path.abspath(name)).name if ("/" in name or name in (".", "..")) else name
    if not folder or not re.fullmatch(r"[^\x00-\x1f/]+", folder):
        raise DatasetError(f"{name!r}: not a scene name or a folder a scene can be named after")
    return folder


def _folder_name(name: str, parent: Path) -> str:
    """A dataset name that is one folder name under `parent`; a path (that could lead out of it) is refused."""
    clean = name.rstrip("/")
    if "/" in clean or clean in (".", "..") or "\0" in clean:
        raise DatasetError(
            f"{name!r}: a TUM sequence name is one folder name under {parent}/, not a path; "
            f"to open a folder elsewhere, pass its path (e.g. ./{clean.split('/')[0]})"
        )
    return clean


def open_folder(folder: Path) -> Sequence:
    """The reader for a folder, told apart by the files each dataset ships."""
    for reader in READERS.values():
        if reader.recognizes(folder):
            return reader(folder)
    raise DatasetError(
        f"{folder}: neither a ScanNet scene (no *_vh_clean_2.labels.ply), a TUM RGB-D sequence (no rgb.txt) nor a "
        f"ROS 2 bag (no metadata.yaml)"
    )
