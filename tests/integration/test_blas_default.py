"""One BLAS thread is the command-line tools' default, never a side effect of importing the library."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

IMPORTS = """import os
import clipclique.pipeline, clipclique.io.mapfile, clipclique.benchmark.suite, clipclique.localization.run, clipclique.mapping.build
print(os.environ.get("OPENBLAS_NUM_THREADS"), os.environ.get("HF_HUB_OFFLINE"))
"""  # noqa: E501 (the import line is code the subprocess runs)
ENTRY = """import os, sys
sys.argv = ["tool", "--version"]
from {module} import main
try:
    main()
except SystemExit:
    pass
print(os.environ.get("OPENBLAS_NUM_THREADS"))
"""


def probe(code: str, **environment: str) -> list[str]:
    env = {key: value for key, value in os.environ.items()
           if key not in ("OPENBLAS_NUM_THREADS", "HF_HUB_OFFLINE")} | environment
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return done.stdout.split()


def test_importing_the_library_sets_nothing():
    assert probe(IMPORTS) == ["None", "None"]


@pytest.mark.parametrize("module", ["clipclique.localization.cli", "clipclique.mapping.cli",
                                    "clipclique.benchmark.cli"])
def test_each_tool_defaults_to_one_thread_and_a_users_setting_wins(module):
    assert probe(ENTRY.format(module=module))[-1] == "1"
    assert probe(ENTRY.format(module=module), OPENBLAS_NUM_THREADS="4")[-1] == "4"
