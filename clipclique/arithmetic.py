"""The process's floating-point arithmetic, pinned before numpy loads, so that a run gives the same results to
the bit on any x86-64 machine with AVX2 and FMA (Intel since 2013, AMD since Zen).

OpenBLAS picks its kernels by CPU, and its AVX-512 kernels add a small product's terms in another order than
its AVX2 ones; numpy's AVX-512 loops (exp, log, trigonometry) round otherwise than its AVX2 ones. A pose's last
bits then differ from one machine to the next, and now and then a decision that rests on them (a match, a
ranking), so a figure measured on one machine would not reproduce on another. Pinned here: OpenBLAS's Haswell
kernels (AVX2 and FMA) and numpy's dispatch up to x86-64-v3, and one OpenBLAS thread (a query's matrices are
tiny: BLAS threads only wait for busy cores, up to ~10 ms a query on 2 cores, tools/bench.py). A setting the
user made in the environment is kept. This module imports nothing heavy: the entry points call `pin_arithmetic`
first, while numpy is not yet loaded (it reads these variables once, when it loads).
"""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path

# OpenBLAS's AVX2 + FMA kernels, and numpy's dispatch without its AVX-512 targets (numpy >= 2.4 names them so)
X86_64_PINS = {"OPENBLAS_CORETYPE": "Haswell", "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}


def pin_arithmetic() -> bool:
    """Sets the pins (where the environment does not already say otherwise); whether they take effect: numpy not
    loaded yet. Off x86-64, or on a CPU without AVX2 and FMA, only the thread count is pinned."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if _has_avx2_and_fma():
        for variable, value in X86_64_PINS.items():
            os.environ.setdefault(variable, value)
    return "numpy" not in sys.modules


def _has_avx2_and_fma(cpuinfo: Path = Path("/proc/cpuinfo")) -> bool:
    """Whether this is an x86-64 Linux machine whose CPU flags list avx2 and fma (elsewhere nothing is pinned)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        text = cpuinfo.read_text()
    except OSError:
        return False
    flags = next((line.split(":", 1)[1].split() for line in text.splitlines() if line.startswith("flags")), [])
    return "avx2" in flags and "fma" in flags
