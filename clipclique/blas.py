"""One BLAS thread by default for the command-line tools, a speed setting: a query's matrices are 3 x 3 to about
50 x 50, and OpenBLAS's threads only wait for busy cores there (up to ~10 ms a query on 2 cores, tools/bench.py).

The entry points call `one_blas_thread_by_default` before numpy loads (OpenBLAS reads the variable once, when it
loads); a user's own OPENBLAS_NUM_THREADS wins, and importing a library module never sets it."""

from __future__ import annotations

import os


def one_blas_thread_by_default() -> None:
    """OPENBLAS_NUM_THREADS=1 unless the environment already says otherwise."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
