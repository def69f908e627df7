"""From a scene name as a user types it to an open sequence and its default detector.

A generated scene's name (clipclique.sim.DEMO_SCENES) is generated first, as an explicit step, and
opened as the ordinary dataset folder it is; every other name goes to the dataset readers.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from clipclique import sim
from clipclique.datasets import Sequence, open_folder, open_sequence, resolve_data_root


def open_scene(name: str, data_root: Path | None = None,
               progress: Callable[[int, int], None] | None = None) -> Sequence:
    """The sequence `name` names (`open_sequence`'s names and paths, and the generated scenes'),
    generating a generated scene under `<data_root>/demo/` on first use (`progress` per frame)."""
    if name in sim.DEMO_SCENES:
        return open_folder(sim.ensure_scene(name, resolve_data_root(data_root), progress))
    return open_sequence(name, data_root)


def first_use_notice(name: str, data_root: Path | None = None) -> str | None:
    """The line to say before `open_scene` generates the scene `name` (tens of seconds); None when it will not."""
    return sim.first_use_notice(name, resolve_data_root(data_root))


def default_detector(sequence: Sequence) -> str:
    """The `--detector` a sequence gets unless asked: a generated scene's own (clipclique.sim), else its
    reader's (gt on ScanNet, annotations on TUM)."""
    return sim.scene_detector(sequence.root) or sequence.default_detector
