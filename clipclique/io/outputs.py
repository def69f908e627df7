"""Outputs of a run that appear together and whole, or not at all.

Each output is written to `<name>.partial` beside its target and moved into place by
`Staging.commit` once everything succeeded; an error, Ctrl-C or SIGTERM before that removes
the partial files and leaves the previous outputs byte-identical.
The tools' default output folders (relative to the working folder) are defined here, once.
"""

from __future__ import annotations

import glob
import os
import signal
import threading
from pathlib import Path
from types import FrameType, TracebackType

from clipclique.errors import ClipcliqueError

PARTIAL_SUFFIX = ".partial"
MAP_DIR = Path("outputs/maps")  # clipclique-map writes, clipclique-loc and the benchmark look up
LOC_DIR = Path("outputs/loc")  # clipclique-loc's run folders
BENCH_DIR = Path("outputs/bench")  # the benchmark's reports
CACHE_DIR = Path("outputs/cache")  # the benchmark's perception cache (clipclique.benchmark.perception)


def map_file(scene: str) -> Path:
    """Where the map of `scene` (its short name, as `datasets.scene_name` gives it) is written and found."""
    return MAP_DIR / f"{scene}.map.npz"


class Staging:
    """A set of outputs committed together. Use as a context manager; call `commit()` at the end."""

    def __init__(self) -> None:
        self._moves: list[tuple[Path, Path]] = []
        self._removals: list[Path] = []
        self._previous_handlers: dict[int, object] = {}  # signal -> its handler before this staging
        self._interrupted: int | None = None  # the signal that asked the run to stop

    def path(self, target: Path) -> Path:
        """Where to write `target` for now; refuses, before any work, a target that cannot be replaced."""
        target = Path(target)
        if target.is_dir():
            raise ClipcliqueError(f"{target}: is a folder; cannot write the output there (remove it "
                                  "or choose another path)")
        partial = target.with_name(target.name + PARTIAL_SUFFIX)
        self._moves.append((partial, target))
        return partial

    def remove(self, target: Path) -> None:
        """Delete `target` at commit (an output of an earlier run that would no longer match)."""
        self._removals.append(Path(target))

    def commit(self) -> None:
        """Move every staged output into place (each move is atomic) and delete the removals; never after Ctrl-C
        or SIGTERM, even where a library swallowed the exception the signal raised (see `_stop`)."""
        if self._interrupted is not None:
            _raise_for(self._interrupted)
        missing = [str(partial) for partial, _ in self._moves if not partial.is_file()]
        if missing:
            raise ClipcliqueError(f"outputs not written: {', '.join(missing)}")
        try:
            for partial, target in self._moves:
                os.replace(partial, target)
            for target in self._removals:
                target.unlink(missing_ok=True)
        except OSError as error:
            raise ClipcliqueError(f"{error.filename}: cannot move the output into place ({error.strerror})") from None
        self._moves.clear()

    def discard(self) -> None:
        """Delete whatever was staged and not committed, with any temporary its writer made beside it
        (`<partial>.*`: a writer interrupted before it could clean up after itself)."""
        for partial, _ in self._moves:
            for path in (partial, *partial.parent.glob(glob.escape(partial.name) + ".*")):
                path.unlink(missing_ok=True)
        self._moves.clear()

    def __enter__(self) -> Staging:
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                previous = signal.getsignal(signum)
                if previous is not signal.SIG_IGN:  # a background job's ignored Ctrl-C stays ignored
                    self._previous_handlers[signum] = previous
                    signal.signal(signum, self._stop)
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        try:
            self.discard()
        finally:
            for signum, previous in self._previous_handlers.items():
                signal.signal(signum, previous)
            self._previous_handlers.clear()

    def _stop(self, signum: int, frame: FrameType | None) -> None:
        """Ctrl-C and SIGTERM unwind (SIGTERM like Ctrl-C), so that context managers clean their partial files.
        The signal is also remembered: its exception lands wherever Python happens to be, and compiled code
        there may swallow it (pyarrow's first `pa.array` imports pandas inside a Cython function that can only
        print an exception as ignored), which would let the run go on and commit."""
        self._interrupted = signum
        _raise_for(signum)


def _raise_for(signum: int) -> None:
    """What Python raises for Ctrl-C; SIGTERM as the exit status a shell gives a terminated program."""
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise SystemExit(128 + signum)
