"""One `.rrd` file per run, written to a temporary name and moved into place only when complete."""

from __future__ import annotations

import dataclasses
import functools
import os
import queue
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from types import TracebackType
from typing import TypeVar

import numpy as np
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


Row = TypeVar("Row")


class ColumnsAtClose:
    """Per-frame data that need not reach the stream while the run goes (the recording is complete only at the end
    anyway), kept until the run ends and then sent as one column per entity and component: one Rerun call each per
    run, where logging it frame by frame took a call per entity per frame on the recorder's thread (Python work
    under the GIL the run needs). Rows are kept as plain values (scalars, clears, an archetype's fields: see
    ArchetypeRows) and built into archetypes only at the end. A viewer sees the same values at the same frames; a run
    killed before `send` loses them. Small data only: images belong on the stream."""

    def __init__(self) -> None:
        # (path, how rows become columns) -> [(frame, stamp, row)]
        self._rows: dict[tuple[str, Callable[[list], Iterable[rr.ComponentColumn]]],
                         list[tuple[int, float | None, object]]] = {}

    def add(self, path: str, frame: int, timestamp: float | None, row: Row,
            columns: Callable[[list[Row]], Iterable[rr.ComponentColumn]]) -> None:
        """`row` at `frame` (and at `timestamp` on the timeline `time`, unless None); `columns` makes the
        component columns of a list of such rows, one row each."""
        self._rows.setdefault((path, columns), []).append((frame, timestamp, row))

    def scalar(self, path: str, frame: int, timestamp: float | None, value: float) -> None:
        self.add(path, frame, timestamp, float(value), scalar_columns)

    def clear(self, path: str, frame: int, timestamp: float | None, *, recursive: bool = False) -> None:
        """A Clear at `frame` (e.g. a gap, so a plot draws no line across it)."""
        self.add(path, frame, timestamp, recursive, clear_columns)

    def send(self, stream: rr.RecordingStream, *, full: int | None = None) -> None:
        """Everything added, as columns, rows with a timestamp and without apart (a column's timelines cover
        all its rows); with `full`, only the entities holding that many rows (images: a few frames at a time, where
        a call a frame cost Rerun's archetype building each time, and memory stays bounded)."""
        sent = [key for key, rows in self._rows.items() if full is None or len(rows) >= full]
        for path, columns in sent:
            rows = self._rows.pop((path, columns))
            for stamped in (True, False):
                part = [row for row in rows if (row[1] is not None) == stamped]
                if not part:
                    continue
                frames, stamps, values = zip(*part)
                indexes = [rr.TimeColumn("frame", sequence=frames)]
                if stamped:
                    indexes.append(rr.TimeColumn("time", timestamp=stamps))
                stream.send_columns(path, indexes=indexes, columns=columns(list(values)))


@dataclasses.dataclass(frozen=True)
class ArchetypeRows:
    """How rows of plain fields become `archetype`'s columns at close (the `columns` of `ColumnsAtClose.add`): one
    `archetype.columns` over every row, where building the archetype frame by frame cost its Python conversions
    each frame. A row holds what `archetype(**row)` would take (after `convert`): the fields in `instanced` one
    value per instance (arrays or lists, each of the row's instance count; those a row leaves out are not logged),
    the others one value a row (a splat, as a single colour or radius is logged). A viewer sees what logging
    `archetype(**row)` at the row's frame shows."""

    archetype: type
    instanced: tuple[str, ...] = ()
    convert: Callable[[dict], dict] | None = None  # the joined instanced fields into the archetype's

    def __call__(self, rows: list[dict]) -> list[rr.ComponentColumn]:
        columns = []
        instanced = [name for name in self.instanced if name in rows[0]]
        if instanced:
            lengths = [len(row[instanced[0]]) for row in rows]
            joined = {name: _join([row[name] for row in rows]) for name in instanced}
            if self.convert is not None:
                joined = self.convert(joined)
            columns += self.archetype.columns(**joined).partition(lengths)
        per_row = {name: [row[name] for row in rows] for name in rows[0] if name not in self.instanced}
        if per_row:
            columns += self.archetype.columns(**per_row)
        return columns


def _join(parts: list) -> np.ndarray | list:
    """The rows' instances one after another: arrays concatenated, lists chained."""
    if isinstance(parts[0], np.ndarray):
        return np.concatenate(parts)
    return [value for part in parts for value in part]


def scalar_columns(values: list[float]) -> Iterable[rr.ComponentColumn]:
    return rr.Scalars.columns(scalars=values)


def clear_columns(recursive: list[bool]) -> Iterable[rr.ComponentColumn]:
    return rr.Clear.columns(is_recursive=recursive)
