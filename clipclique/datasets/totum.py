"""A ROS bag written as a TUM RGB-D folder (`clipclique-loc convert BAG --to-tum DIR`), so that every tool that
reads TUM folders (this project's, evo, ORB-SLAM's examples, ...) reads the recording.

The folder holds what clipclique.datasets.tum reads back as the bag's frames:
- `rgb/<stamp>.png` (RGB) and `depth/<stamp>.png` (uint16, metres x DEPTH_FACTOR, 0 = missing; depth beyond
  the uint16 range, 13.1 m, is written as missing), both named by the frame's colour stamp (`%.6f`, the bag pairs
  each colour image with its depth image), listed in `rgb.txt` and `depth.txt`;
- `intrinsics.txt`: the frames' K (`fx fy cx cy`, the bag's CameraInfo K at the images' size);
- `groundtruth.txt`: the pose of each frame that has one (no file when none has).
It is written into a sibling `DIR.partial-XXXX` and renamed to DIR once whole: a failure or Ctrl-C leaves
nothing behind, and a folder that already holds files is refused, never overwritten.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clipclique.datasets.rosbag import BagSequence
from clipclique.datasets.tum import DEPTH_FACTOR, tum_line
from clipclique.errors import DatasetError
from clipclique.types import Frame

Progress = Callable[[int, int], None]  # (frames written, frames to write)


@dataclass(frozen=True)
class ConversionSummary:
    """What `write_tum_folder` wrote, for the line the command prints."""

    frames: int
    poses: int  # frames with a ground-truth pose (lines of groundtruth.txt)
    out: Path
    files: tuple[str, ...]  # what the folder holds: "rgb/", "depth/", "rgb.txt", ...


def check_target(out: Path) -> None:
    """Refuse a DIR that is a file or a folder holding anything: the user's files are never replaced."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        what = "a folder that is not empty" if out.is_dir() else "not a folder"
        raise DatasetError(f"{out}: exists and is {what}; choose a new folder (nothing there is changed)")


def write_tum_folder(
    sequence: BagSequence, out: Path, indices: range | None = None, progress: Progress | None = None
) -> ConversionSummary:
    """Write the frames `indices` (all by default) of `sequence` as the TUM folder `out`, whole or not at all."""
    out = Path(out)
    check_target(out)
    indices = range(len(sequence)) if indices is None else indices
    try:
        staging = _staging_folder(out)
    except OSError as error:
        raise _unwritable(out, error) from None
    try:
        poses, files = _write(sequence, staging, indices, progress)
        os.replace(staging, out)  # replaces an empty folder; one that gained files meanwhile fails here
    except BaseException as error:
        shutil.rmtree(staging, ignore_errors=True)
        if isinstance(error, OSError):
            raise _unwritable(out, error) from None
        raise
    return ConversionSummary(len(indices), poses, out, files)


def _staging_folder(out: Path) -> Path:
    """A new `OUT.partial-XXXX` beside `out`, with the permissions a folder made by mkdir would have (mkdtemp
    makes it private to its owner)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f"{out.name}.partial-", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    staging.chmod(0o777 & ~umask)
    return staging


def _unwritable(out: Path, error: OSError) -> DatasetError:
    return DatasetError(f"{out}: cannot write the TUM folder ({error})")


def _write(
    sequence: BagSequence, folder: Path, indices: range, progress: Progress | None
) -> tuple[int, tuple[str, ...]]:
    """Every file of the TUM folder into `folder` (the staging folder); (poses written, the files)."""

    (folder / "rgb").mkdir()
    (folder / "depth").mkdir()
    rgb_lines, depth_lines, pose_lines = ["# timestamp filename"], ["# timestamp filename"], []
    intrinsics = None
    for done, i in enumerate(indices, start=1):
        frame = sequence[i]
        name = sequence.frame_name(i)
        if (folder / "rgb" / f"{name}.png").exists():
            raise DatasetError(f"{sequence.root}: two colour images have the stamp {name}; a TUM folder names "
                               "its files by stamp")
        intrinsics = _same_intrinsics(intrinsics, frame, sequence)
        _write_png(frame.rgb, folder / "rgb" / f"{name}.png")
        _write_png(depth_units(frame.depth), folder / "depth" / f"{name}.png")
        rgb_lines.append(f"{name} rgb/{name}.png")
        depth_lines.append(f"{name} depth/{name}.png")
        if frame.pose is not None:
            pose_lines.append(tum_line(frame.timestamp, frame.pose))
        if progress is not None:
            progress(done, len(indices))
    files = ["rgb/", "depth/", "rgb.txt", "depth.txt", "intrinsics.txt"]
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    values = (intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2])  # exact: repr round-trips
    (folder / "intrinsics.txt").write_text("# fx fy cx cy (pixels)\n" + " ".join(repr(float(v)) for v in values) + "\n")
    if pose_lines:
        files.append("groundtruth.txt")
        text = "\n".join(["# timestamp tx ty tz qx qy qz qw (camera-to-world)", *pose_lines]) + "\n"
        (folder / "groundtruth.txt").write_text(text)
    return len(pose_lines), tuple(files)


def _same_intrinsics(first: np.ndarray | None, frame: Frame, sequence: BagSequence) -> np.ndarray:
    """The frame's K, which must be every frame's: a TUM folder has one intrinsics.txt."""
    if first is not None and not np.array_equal(first, frame.intrinsics):
        raise DatasetError(f"{sequence.root}: the depth image's size changes at {frame.name}; a TUM folder has one "
                           "camera matrix for all its frames")
    return frame.intrinsics


def depth_units(depth: np.ndarray) -> np.ndarray:
    """Metres as TUM's uint16 units (DEPTH_FACTOR per metre): NaN, infinite, not positive or beyond the uint16
    range (13.1 m) -> 0, missing: a clipped value would be a false reading at 13.1 m."""
    units = np.round(np.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float64) * DEPTH_FACTOR)
    units[(units < 0) | (units > np.iinfo(np.uint16).max)] = 0
    return units.astype(np.uint16)


def _write_png(pixels: np.ndarray, path: Path) -> None:
    from PIL import Image

    Image.fromarray(pixels).save(path, "PNG")
