"""One `.rrd` file per run, written to a temporary name and moved into place only when complete."""

from __future__ import annotations

import functools
import os
import queue
import threading
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


class Worker:
    """Runs logging jobs on one thread of its own, in order, so encoding images and building Rerun's
    arrow batches stay off the caller's thread (PIL's encoders and Rerun's batching release the GIL).

    At most `backlog` jobs wait: a caller that outruns the worker blocks instead of holding every
    frame in memory. A job's exception is raised in the caller's thread by the next `submit`,
    `drain` or `stop`, and no later job runs.
    """

    def __init__(self, name: str, backlog: int = 4) -> None:
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue(maxsize=backlog)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Callable[[], None]) -> None:
        self._raise()
        self._jobs.put(job)

    def drain(self) -> None:
        """Wait until every submitted job has run."""
        self._jobs.join()
        self._raise()

    def stop(self, *, discard: bool = False) -> None:
        """Finish the submitted jobs (or drop them when `discard`) and end the thread."""
        if discard:
            self._error = self._error or _Discarded()
        self._jobs.put(None)
        self._thread.join()
        if not discard:
            self._raise()

    def _serve(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                if self._error is None:
                    job()
            except BaseException as error:  # handed to the caller's thread
                self._error = error
            finally:
                self._jobs.task_done()
        self._jobs.task_done()

    def _raise(self) -> None:
        if self._error is not None and not isinstance(self._error, _Discarded):
            raise self._error


def queued(method: Callable[..., None]) -> Callable[..., None]:
    """A method of an object with a `_worker` (a Worker) that runs there: the caller only queues the call."""
    @functools.wraps(method)
    def submit(self, *args, **kwargs) -> None:
        self._worker.submit(functools.partial(method, self, *args, **kwargs))
    return submit


class _Discarded(Exception):
    """Marks a worker whose remaining jobs are dropped (the run failed)."""


class ScalarColumns:
    """Per-frame scalars (and the frames where a series has a gap) kept until the run ends and then sent as one
    column per series: one call per series per run, where logging them frame by frame took about fifteen
    Rerun calls a frame on the recorder's thread, each building archetypes under the GIL the run needs."""

    def __init__(self) -> None:
        self._rows: dict[str, list[tuple[int, float | None, float | None]]] = {}  # path -> (frame, stamp, value)

    def add(self, path: str, frame: int, timestamp: float | None, value: float) -> None:
        """`value` at `frame` (and at `timestamp` on the timeline `time`, unless None)."""
        self._rows.setdefault(path, []).append((frame, timestamp, float(value)))

    def clear(self, path: str, frame: int, timestamp: float | None) -> None:
        """A gap at `frame`: a Clear, so the plot draws no line across it."""
        self._rows.setdefault(path, []).append((frame, timestamp, None))

    def send(self, stream: rr.RecordingStream) -> None:
        """Everything added, as columns: values and gaps of each series, rows with a timestamp and without apart
        (a column's timelines cover all its rows)."""
        for path, rows in self._rows.items():
            for cleared in (False, True):
                for stamped in (True, False):
                    part = [row for row in rows if (row[2] is None) == cleared and (row[1] is not None) == stamped]
                    if not part:
                        continue
                    frames, stamps, values = zip(*part)
                    indexes = [rr.TimeColumn("frame", sequence=frames)]
                    if stamped:
                        indexes.append(rr.TimeColumn("time", timestamp=stamps))
                    columns = (rr.Clear.columns(is_recursive=[False] * len(part)) if cleared
                               else rr.Scalars.columns(scalars=values))
                    stream.send_columns(path, indexes=indexes, columns=columns)
        self._rows.clear()
