"""Hostile inputs against `clipclique-loc convert BAG --to-tum DIR` (issue 36): each ends with exit code 2 and one
line naming what is wrong, a user's files untouched, and no DIR (nor a DIR.partial-* staging folder) left behind."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from clipclique.datasets.rosbag import BagSequence
from clipclique.errors import DatasetError
from clipclique.localization.cli import app

RUNNER = CliRunner()


@pytest.fixture(scope="module")
def bags(demo_data, bag_tools, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("convert-fuzz")
    folder = demo_data("demo_tum") / "demo" / "demo_tum"
    return {
        "ros1": bag_tools.write_bag(folder, root / "rec.bag"),
        "mcap": bag_tools.write_bag(folder, root / "rec", "mcap") / "rec.mcap",
    }


def refused(result, *texts: str, code: int = 2) -> str:
    assert result.exit_code == code, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("clipclique-loc: "), result.output
    assert "Traceback" not in result.output and all(text in lines[0] for text in texts), result.output
    return lines[0]


def convert(bag: Path, out: Path, *args: str):
    return RUNNER.invoke(app, ["convert", str(bag), "--to-tum", str(out), *args])


def left_behind(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.glob(f"{out.name}*"))


@pytest.mark.parametrize("kind", ["folder", "file"])
def test_a_users_folder_or_file_is_never_touched(bags, tmp_path, kind):
    out = tmp_path / "mine"
    if kind == "folder":
        out.mkdir()
        (out / "notes.txt").write_text("my notes\n")
    else:
        out.write_text("my notes\n")
    refused(convert(bags["ros1"], out), str(out), "exists and is", "nothing there is changed")
    assert (out / "notes.txt" if kind == "folder" else out).read_text() == "my notes\n"
    assert left_behind(out) == ["mine"] and (not out.is_dir() or sorted(p.name for p in out.iterdir()) == ["notes.txt"])


@pytest.mark.parametrize("name", ["notes.txt", "folder"])
def test_a_path_that_is_not_a_bag_is_one_line(tmp_path, name):
    path = tmp_path / name
    path.mkdir() if name == "folder" else path.write_text("not a bag\n")
    refused(convert(path, tmp_path / "out"), f"{path}: not a ROS bag (a .bag, .mcap or .db3 file")
    assert left_behind(tmp_path / "out") == []


@pytest.mark.parametrize("storage", ["ros1", "mcap"])
@pytest.mark.parametrize("keep", [0.3, 0.7])
def test_a_truncated_bag_leaves_nothing(bags, tmp_path, storage, keep):
    cut = tmp_path / bags[storage].name
    data = bags[storage].read_bytes()
    cut.write_bytes(data[: int(len(data) * keep)])
    refused(convert(cut, tmp_path / "out"), str(cut))
    assert left_behind(tmp_path / "out") == []


@pytest.mark.parametrize("flag", ["--rgb-topic", "--depth-topic", "--camera-info-topic"])
def test_a_topic_that_does_not_exist_is_one_line(bags, tmp_path, flag):
    refused(convert(bags["ros1"], tmp_path / "out", flag, "/nope"), str(bags["ros1"]), f"{flag} /nope: no such topic")
    assert left_behind(tmp_path / "out") == []


@pytest.mark.parametrize("failure, code, text", [
    (DatasetError("frame 2 is damaged"), 2, "clipclique-loc: error: frame 2 is damaged"),
    (KeyboardInterrupt(), 130, "clipclique-loc: interrupted"),
    (OSError(28, "No space left on device"), 2, "cannot write the TUM folder ([Errno 28] No space left on device)"),
])
def test_a_failure_half_way_leaves_nothing(bags, tmp_path, monkeypatch, failure, code, text):
    """Frames 0 and 1 are written into the staging folder, frame 2 fails: the staging folder goes, DIR never appears."""
    read = BagSequence.__getitem__

    def failing(self, i):
        if i == 2:
            assert len(list(tmp_path.glob("out.partial-*/rgb/*.png"))) == 2  # written so far, not in DIR
            raise failure
        return read(self, i)

    monkeypatch.setattr(BagSequence, "__getitem__", failing)
    refused(convert(bags["ros1"], tmp_path / "out", "-q"), text, code=code)
    assert left_behind(tmp_path / "out") == []


def test_a_folder_under_a_file_is_one_line(bags, tmp_path):
    (tmp_path / "a-file").write_text("mine\n")
    refused(convert(bags["ros1"], tmp_path / "a-file" / "out", "-q"), f"{tmp_path / 'a-file' / 'out'}: cannot write")
    assert (tmp_path / "a-file").read_text() == "mine\n"
