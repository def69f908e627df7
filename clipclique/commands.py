"""How to type a command of this installation in a hint the tools print, so the hint runs as written."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path


def command(name: str) -> str:
    """`name` (a console script: rerun, clipclique-map, ...) as the user can type it here: bare when the
    shell finds this installation's copy on PATH, else its path beside this interpreter (`.venv/bin/rerun`)."""
    beside = Path(sys.executable).parent / name
    if not beside.is_file():
        return name
    found = shutil.which(name)
    if found is not None and Path(found).resolve() == beside.resolve():
        return name
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


def rerun_hint(path: Path | str) -> str:
    return f"open with: {command('rerun')} {path}"

