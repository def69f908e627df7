"""From a scene name as a user types it to an open sequence and its default detector.

A generated scene's name (clipclique.sim.DEMO_SCENES) is generated first, as an explicit step, and
opened as the ordinary dataset folder it is; every other name goes to the dataset readers.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable
from pathlib import Path

from clipclique import sim
from clipclique.datasets import TUM_SHORT_NAMES, BagOptions, Sequence, open_folder, open_sequence, resolve_data_root
from clipclique.errors import DatasetError, one_line


def open_scene(name: str, data_root: Path | None = None,
               progress: Callable[[int, int], None] | None = None, bag: BagOptions | None = None) -> Sequence:
    """The sequence `name` names (`open_sequence`'s names and paths, a bag read with the `bag` options, and the
    generated scenes'), generating a generated scene under `<data_root>/demo/` on first use (`progress` per frame)."""
    if name in sim.DEMO_SCENES:
        return open_folder(sim.ensure_scene(name, resolve_data_root(data_root), progress))
    try:
        return open_sequence(name, data_root, bag)
    except DatasetError as error:
        if (near := nearest_scene(name, data_root)) is None:
            raise
        raise DatasetError(f"{one_line(error)}; did you mean {near}?") from None


def check_scene(name: str, data_root: Path | None = None) -> None:
    """Refuse a name that names no scene (with the nearest one that does), generating nothing."""
    if name not in sim.DEMO_SCENES:
        open_scene(name, data_root)


def nearest_scene(name: str, data_root: Path | None = None) -> str | None:
    """For a name that is no scene here (not generated, not a short or dataset name whose folder exists, not a
    path), the nearest one that is; None otherwise, and when none is near."""
    root = resolve_data_root(data_root)
    folders = [folder.name for parent in (root / "tum", root / "scannet" / "scans") if parent.is_dir()
               for folder in parent.iterdir() if folder.is_dir()]
    known = [*sim.DEMO_SCENES, *TUM_SHORT_NAMES, *folders]
    if name in known or "/" in name or Path(name).exists():
        return None
    near = difflib.get_close_matches(name, known, n=1, cutoff=0.75)
    return near[0] if near else None


def first_use_notice(name: str, data_root: Path | None = None) -> str | None:
    """The line to say before `open_scene` generates the scene `name` (tens of seconds); None when it will not."""
    return sim.first_use_notice(name, resolve_data_root(data_root))


def default_detector(sequence: Sequence) -> str:
    """The `--detector` a sequence gets unless asked: a generated scene's own (clipclique.sim), else its
    reader's (gt on ScanNet, annotations on TUM)."""
    return sim.scene_detector(sequence.root) or sequence.default_detector
