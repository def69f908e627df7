"""One `.rrd` file per run, written to a temporary name and moved into place only when complete."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

import rerun as rr
import rerun.blueprint as rrb


class RecordingFile:
    """A RecordingStream that saves to `path`; nothing spawns a viewer.

    A run that dies half-way leaves no `.rrd` behind, so a file at `path` is always a complete
    recording. `blueprint` is called on close, so the layout can fit what was logged (e.g. frame
    the whole trajectory).
    """

    def __init__(self, path: Path, application_id: str, blueprint: Callable[[], rrb.Blueprint]) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._partial = self.path.with_name(self.path.name + ".partial")
        self.stream = rr.RecordingStream(application_id)
        self.stream.set_log_time_enabled(False)  # wall-clock columns add size and break reproducibility
        self.stream.set_log_tick_enabled(False)
        self.stream.save(self._partial)
        self.blueprint = blueprint

    def close(self) -> None:
        try:
            self.stream.send_blueprint(self.blueprint(), make_active=True, make_default=True)
            self.stream.flush()
        except BaseException:
            self.abort()  # no .partial left behind when the layout cannot be made
            raise
        self.stream.disconnect()
        os.replace(self._partial, self.path)

    def abort(self) -> None:
        self.stream.disconnect()
        self._partial.unlink(missing_ok=True)

    def __enter__(self) -> RecordingFile:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()
