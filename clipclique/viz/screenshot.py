"""Render a Rerun recording to PNG with no display, as a user would first see it.

The viewer runs headless on Mesa's software Vulkan driver (lavapipe) and is driven through
rerun's viewer-control API: open the file, wait until it is loaded, optionally move the time
cursor, then screenshot until two consecutive frames agree (images decode asynchronously, so the
first paint can still lack them). The views' own warnings come back with the picture.

    .venv/bin/python tools/screenshot.py outputs/maps/demo.map.rrd docs/map_recording.png
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import rerun_cli
from rerun.experimental import ViewerClient

VULKAN_ICD_DIRS = (Path("/usr/share/vulkan/icd.d"), Path("/etc/vulkan/icd.d"))
VIEWER_ENV = {"WGPU_BACKEND": "vulkan", "RUST_LOG": "off"}  # error-only: no warning toasts in the picture
STABLE_TRIES = 6
STARTUP_TOAST_S = 4.5  # the viewer's "listening on port ..." notification fades after about 4 s


@dataclass
class Screenshot:
    png: bytes
    view_reports: list[str]  # "view name: severity: summary" for each view that failed to show something
    seconds: float
    warnings: list[str]  # what was asked but not shown (a --frame the recording does not hold)


def software_vulkan_available() -> bool:
    """Whether Mesa's lavapipe (mesa-vulkan-drivers) is installed."""
    return any(any(folder.glob("lvp_icd*.json")) for folder in VULKAN_ICD_DIRS if folder.is_dir())


def viewer_binary() -> Path:
    return Path(rerun_cli.__file__).parent / "rerun"


def render(
    recording: Path,
    size: tuple[int, int] = (1280, 960),
    frame: int | None = None,
    timeout_s: float = 120.0,
) -> Screenshot:
    """Screenshot `recording` in a fresh headless viewer, at `frame` on the `frame` timeline or the end."""
    start = time.monotonic()
    deadline = start + timeout_s
    port = _free_port()
    with tempfile.TemporaryFile() as log:
        viewer = subprocess.Popen(
            [str(viewer_binary()), "--headless", "--hide-welcome-screen", "--port", str(port),
             "--window-size", f"{size[0]}x{size[1]}"],
            env={**os.environ, **VIEWER_ENV},
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            client = _connect(port, viewer, deadline, log)
            client.open(str(Path(recording).resolve()))
            while client.get_state().loading:
                _check_time(deadline, "loading the recording")
                time.sleep(0.2)
            warnings: list[str] = []
            if frame is not None:
                frame = _frame_held(client, frame, warnings)
            if frame is not None:
                client.set_time("frame", sequence=frame, play_state="paused")
            time.sleep(max(0.0, start + STARTUP_TOAST_S - time.monotonic()))
            png = _stable_screenshot(client, deadline)
            reports = [
                f"{view.name}: {report.severity}: {report.summary}"
                for view in client.get_state().views
                for report in view.reports
            ]
        finally:
            viewer.terminate()
            try:
                viewer.wait(timeout=10)
            except subprocess.TimeoutExpired:
                viewer.kill()
                viewer.wait()
    return Screenshot(png, reports, time.monotonic() - start, warnings)


def _frame_held(client: ViewerClient, frame: int, warnings: list[str]) -> int | None:
    """`frame` within the range of the loaded recording's `frame` timeline (the nearest end beyond it, with a
    warning); None, with a warning, when the recording has no such timeline (a map recording)."""
    timelines = [t for r in client.get_state().recordings for t in r.timelines if t.name == "frame"]
    if not timelines or timelines[0].start is None or timelines[0].end is None:
        warnings.append(f"--frame {frame}: the recording has no frame timeline (a map recording?); showing it whole")
        return None
    first, last = timelines[0].start, timelines[0].end
    if first <= frame <= last:
        return frame
    shown = min(max(frame, first), last)
    warnings.append(f"--frame {frame}: the recording holds frames {first} to {last}; showing frame {shown}")
    return shown


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _connect(port: int, viewer: subprocess.Popen, deadline: float, log: IO[bytes]) -> ViewerClient:
    """Wait for the viewer's server; fail with the viewer's own output if it died."""
    while True:
        if viewer.poll() is not None:
            log.seek(0)
            raise RuntimeError(f"the Rerun viewer exited ({viewer.returncode}): {log.read().decode()[-2000:]}")
        try:
            client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
            client.get_state()
            return client
        except ConnectionError:  # not listening yet
            _check_time(deadline, "starting the viewer")
            time.sleep(0.3)


def _stable_screenshot(client: ViewerClient, deadline: float) -> bytes:
    previous = client.take_screenshot()
    for _ in range(STABLE_TRIES):
        _check_time(deadline, "waiting for a stable picture")
        time.sleep(0.5)
        current = client.take_screenshot()
        if current == previous:
            break
        previous = current
    return previous


def _check_time(deadline: float, doing: str) -> None:
    if time.monotonic() > deadline:
        raise TimeoutError(f"gave up {doing}: the headless viewer took too long")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("output", type=Path)
    parser.add_argument("--size", default="1280x960", help="window size in points, WxH")
    parser.add_argument("--frame", type=int, help="frame to show (default: the last)")
    args = parser.parse_args()
    if not args.recording.is_file():
        parser.error(f"{args.recording}: no such recording")
    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        parser.error(f"--size {args.size}: expected WIDTHxHEIGHT, e.g. 1280x960")
    if not software_vulkan_available():
        parser.exit(2, "no Vulkan driver: install Mesa's (apt-get install mesa-vulkan-drivers)\n")
    shot = render(args.recording, (width, height), args.frame)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    partial = args.output.with_name(args.output.name + ".partial")
    partial.write_bytes(shot.png)
    os.replace(partial, args.output)
    for warning in shot.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    print(f"{args.output}: {len(shot.png) / 1e6:.2f} MB in {shot.seconds:.1f} s")
    for report in shot.view_reports:
        print(f"view report: {report}")


if __name__ == "__main__":
    main()
