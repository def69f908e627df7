"""tools/fit_confidence.py as a user runs it: a mistake is one line and writes nothing."""

from __future__ import annotations

import subprocess
import sys


def test_fit_confidence_needs_two_scenes(tmp_path, repository):
    tool = repository / "tools" / "fit_confidence.py"
    done = subprocess.run([sys.executable, str(tool), "demo", "--out", str(tmp_path / "m.json")], capture_output=True,
                          text=True, cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.strip().splitlines() == [
        "fit_confidence: error: give two scenes or more: the model is measured on a scene it was not fitted on"]
    assert not (tmp_path / "m.json").exists()
