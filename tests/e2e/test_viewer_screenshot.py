"""Each recording as a user first sees it: rendered by the real viewer, headless, on Mesa's software
Vulkan driver, and checked for the content the default blueprint promises (about 7 s per render)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clipclique.viz import LocalizationRecorder, class_colors, write_map_recording
from clipclique.viz import screenshot as tool
from clipclique.viz.style import CORRECT, WRONG

pytestmark = [
    pytest.mark.viewer,
    pytest.mark.skipif(
        not tool.software_vulkan_available(),
        reason="no Vulkan driver to render with: install Mesa's (apt-get install mesa-vulkan-drivers)",
    ),
]
SIZE = (1280, 960)


def pixels_near(image: np.ndarray, color: np.ndarray, tolerance: float = 40.0) -> int:
    return int((np.linalg.norm(image.astype(float) - color.astype(float), axis=-1) < tolerance).sum())


def render(path: Path, frame: int | None = None) -> tuple[np.ndarray, list[str]]:
    shot = tool.render(path, SIZE, frame=frame)
    return np.asarray(Image.open(io.BytesIO(shot.png)).convert("RGB")), shot.view_reports


def test_map_recording_opens_on_the_framed_landmarks(tmp_path, synthetic_run, scene_points):
    map, _ = synthetic_run(num_frames=1)
    path = tmp_path / "room.map.rrd"
    write_map_recording(path, map, *scene_points(), "# Synthetic room")
    image, reports = render(path)
    assert image.shape == (SIZE[1], SIZE[0], 3)
    assert reports == []  # no view says it failed to show something
    view_3d = image[60:-60, : int(SIZE[0] * 0.58)]
    assert view_3d.std() > 20  # not a blank canvas
    seen = [pixels_near(view_3d, color) > 100 for color in class_colors(map.class_names)]
    assert sum(seen) >= 4  # most classes' ellipsoids are in the default view, in their colours


def four_frame_recording(path: Path, synthetic_run) -> Path:
    """A localization recording of 4 frames of the synthetic room (frame 2 with a wrong top-1, see the
    synthetic_run fixture)."""
    map, frames = synthetic_run(num_frames=4)
    with LocalizationRecorder(path, map, "# clipclique on a synthetic room") as recorder:
        for f in frames:
            recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
    return path


def test_localization_recording_opens_with_camera_matches_and_plots(tmp_path, synthetic_run):
    path = four_frame_recording(tmp_path / "recording.rrd", synthetic_run)
    image, reports = render(path, frame=2)  # frame 2 has a wrong top-1 (see the synthetic_run fixture)
    assert reports == []
    view_3d = image[60:-60, : int(SIZE[0] * 0.58)]
    assert pixels_near(view_3d, CORRECT) > 500 and pixels_near(view_3d, WRONG) > 500  # candidate lines
    camera_view = image[60 : int(SIZE[1] * 0.45), int(SIZE[0] * 0.62) :].astype(int)
    grey = (np.ptp(camera_view, axis=-1) < 6) & (camera_view.mean(axis=-1) > 60) & (camera_view.mean(axis=-1) < 170)
    assert grey.mean() > 0.15  # the decoded JPEG's grey background fills the camera view


def test_the_screenshot_command_says_when_a_frame_is_beyond_the_recording(tmp_path, synthetic_run):
    import os
    import subprocess
    import sys

    path = four_frame_recording(tmp_path / "recording.rrd", synthetic_run)
    tool_path = Path(__file__).resolve().parents[2] / "tools" / "screenshot.py"
    env = os.environ | {"PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]])}
    done = subprocess.run([str(tool_path), str(path), str(tmp_path / "late.png"), "--frame", "500"], env=env,
                          capture_output=True, text=True, timeout=180)  # executable, as the README writes it
    assert done.returncode == 0, done.stderr
    assert "warning: --frame 500: the recording holds frames 0 to 3; showing frame 3" in done.stderr
    assert (tmp_path / "late.png").is_file()
