"""The pinned arithmetic (clipclique.arithmetic): the same OpenBLAS kernels and numpy loops on every x86-64 machine
with AVX2 and FMA, so that results and committed figures reproduce from one machine to the next."""

from __future__ import annotations

import ctypes
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clipclique.arithmetic import X86_64_PINS, _has_avx2_and_fma, pin_arithmetic

CPU = Path("/proc/cpuinfo")
PINNED = _has_avx2_and_fma()


def openblas_cores() -> list[str]:
    """The kernel set each OpenBLAS library bundled with numpy and scipy runs (e.g. "Haswell", "SkylakeX")."""
    cores = []
    for folder in (Path(np.__file__).parent.parent / "numpy.libs", Path(np.__file__).parent.parent / "scipy.libs"):
        for library in sorted(folder.glob("*openblas*.so*")):
            handle = ctypes.CDLL(str(library))
            for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename"):
                if hasattr(handle, name):
                    function = getattr(handle, name)
                    function.restype = ctypes.c_char_p
                    cores.append(function().decode())
                    break
    return cores


@pytest.mark.skipif(not PINNED, reason="nothing but the thread count is pinned off x86-64 with AVX2 and FMA")
def test_this_test_process_runs_the_pinned_kernels():
    """tests/conftest.py pins before numpy loads: OpenBLAS runs its Haswell kernels (numpy's and scipy's
    libraries both) and numpy dispatches no AVX-512 loop, whatever this machine's CPU."""
    from numpy._core._multiarray_umath import __cpu_features__

    cores = openblas_cores()
    assert cores and set(cores) == {"Haswell"}
    assert not any(__cpu_features__[feature] for feature in X86_64_PINS["NPY_DISABLE_CPU_FEATURES"].split())
    assert __cpu_features__["AVX2"] and __cpu_features__["FMA3"]


def test_a_fresh_process_is_pinned_before_numpy_loads_and_keeps_the_users_own_settings():
    """A process that calls pin_arithmetic first gets the pins, unless its environment already says otherwise; one
    that loaded numpy first is told the pins came too late."""
    probe = ("import json, os, sys\nfrom clipclique.arithmetic import pin_arithmetic\n"
             "first = pin_arithmetic()\nimport numpy\nlate = pin_arithmetic()\n"
             "print(json.dumps([first, late] + [os.environ.get(v) for v in "
             "('OPENBLAS_CORETYPE', 'NPY_DISABLE_CPU_FEATURES', 'OPENBLAS_NUM_THREADS')]))")
    clean = {key: value for key, value in os.environ.items()
             if key not in (*X86_64_PINS, "OPENBLAS_NUM_THREADS")}
    run = lambda env: json.loads(subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,  # noqa: E731
                                                text=True, check=True).stdout)
    first, late, core, features, threads = run(clean)
    assert (first, late, threads) == (True, False, "1")
    assert (core, features) == ((X86_64_PINS["OPENBLAS_CORETYPE"], X86_64_PINS["NPY_DISABLE_CPU_FEATURES"]) if PINNED
                                else (None, None))
    assert run(clean | {"OPENBLAS_NUM_THREADS": "2", "NPY_DISABLE_CPU_FEATURES": ""})[2:] == [
        X86_64_PINS["OPENBLAS_CORETYPE"] if PINNED else None, "", "2"]


@pytest.mark.parametrize(("flags", "expected"), [
    ("fpu sse sse2 avx fma avx2 bmi2", True),
    ("fpu sse sse2 avx avx2", False),  # no FMA
    ("fpu sse sse2 avx fma", False),  # no AVX2
    ("fpu sse sse2 avx fma4 xavx2", False),  # names that only contain the flags
])
def test_the_cpu_flags_are_read_word_by_word(tmp_path, monkeypatch, flags, expected):
    monkeypatch.setattr("platform.machine", lambda: "x86_64")
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(f"processor\t: 0\nmodel name\t: Some CPU\nflags\t\t: {flags}\n\nprocessor\t: 1\n")
    assert _has_avx2_and_fma(cpuinfo) is expected


def test_no_pin_off_x86_64_or_without_a_cpu_list(tmp_path, monkeypatch):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("flags\t\t: fma avx2\n")
    monkeypatch.setattr("platform.machine", lambda: "aarch64")
    assert not _has_avx2_and_fma(cpuinfo)
    monkeypatch.setattr("platform.machine", lambda: "x86_64")
    assert not _has_avx2_and_fma(tmp_path / "missing")
    assert _has_avx2_and_fma(cpuinfo)


def test_pinning_again_changes_nothing_the_environment_holds(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    assert pin_arithmetic() is False  # numpy is loaded in this process
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"
