"""Staged outputs: all moved into place together, or none, and no *.partial left either way."""

from __future__ import annotations

import signal

import pytest

from clipclique.errors import ClipcliqueError
from clipclique.io.outputs import Staging


def test_commit_moves_every_output_into_place_as_an_ordinary_file(tmp_path):
    (tmp_path / "old.rrd").write_text("stale")
    with Staging() as staging:
        staging.path(tmp_path / "a.json").write_text("new a")
        staging.path(tmp_path / "b.tum").write_text("new b")
        staging.remove(tmp_path / "old.rrd")
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json.partial", "b.tum.partial", "old.rrd"]
        staging.commit()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.tum"]
    assert (tmp_path / "a.json").read_text() == "new a"
    assert (tmp_path / "a.json").stat().st_mode & 0o044 == 0o044  # readable by others, like any output


def test_an_error_before_commit_leaves_the_previous_outputs_byte_identical(tmp_path):
    (tmp_path / "a.json").write_bytes(b"previous run")
    with pytest.raises(RuntimeError), Staging() as staging:
        staging.path(tmp_path / "a.json").write_text("half of the new run")
        raise RuntimeError("the run failed")
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]
    assert (tmp_path / "a.json").read_bytes() == b"previous run"


def test_a_folder_in_the_way_is_refused_before_anything_is_written(tmp_path):
    (tmp_path / "results.json").mkdir()
    with pytest.raises(ClipcliqueError, match=r"results\.json: is a folder"), Staging() as staging:
        staging.path(tmp_path / "results.json")
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_commit_refuses_when_a_staged_output_was_never_written(tmp_path):
    with pytest.raises(ClipcliqueError, match=r"outputs not written: .*b\.tum\.partial"), Staging() as staging:
        staging.path(tmp_path / "a.json").write_text("a")
        staging.path(tmp_path / "b.tum")
        staging.commit()
    assert list(tmp_path.iterdir()) == []


def test_discard_also_removes_what_an_interrupted_writer_left_beside_its_partial(tmp_path):
    with pytest.raises(KeyboardInterrupt), Staging() as staging:
        partial = staging.path(tmp_path / "recording.rrd")
        partial.with_name(partial.name + ".partial").write_text("the writer's own temporary")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("signum, raised", [(signal.SIGTERM, SystemExit), (signal.SIGINT, KeyboardInterrupt)])
def test_a_signal_whose_exception_was_swallowed_still_stops_the_commit(tmp_path, signum, raised):
    """Compiled code may catch the exception a signal raises where it lands (pyarrow's first `pa.array`
    did, importing pandas): the run goes on, but its outputs must not appear."""
    (tmp_path / "a.json").write_bytes(b"previous run")
    # Python's own handler, whatever this process inherited: a background job (`pytest ... &`) starts with
    # Ctrl-C ignored, and an ignored Ctrl-C stays ignored while staging (the next test)
    inherited = signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL)
    try:
        before = signal.getsignal(signum)
        with pytest.raises(raised) as stopped, Staging() as staging:
            staging.path(tmp_path / "a.json").write_text("the interrupted run's")
            try:
                signal.raise_signal(signum)  # the handler runs here, in the main thread
            except BaseException:
                pass  # swallowed, as that library does
            staging.commit()
        assert signal.getsignal(signum) is before  # the caller's handler is back
    finally:
        signal.signal(signum, inherited)
    if signum == signal.SIGTERM:
        assert stopped.value.code == 128 + signal.SIGTERM
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]
    assert (tmp_path / "a.json").read_bytes() == b"previous run"


def test_an_ignored_ctrl_c_stays_ignored_while_staging(tmp_path):
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # a background job's
    try:
        with Staging() as staging:
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            signal.raise_signal(signal.SIGINT)
            staging.path(tmp_path / "a.json").write_text("a")
            staging.commit()
        assert (tmp_path / "a.json").read_text() == "a"
    finally:
        signal.signal(signal.SIGINT, previous)
