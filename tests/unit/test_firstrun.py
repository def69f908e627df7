"""The progress bar's first-run note: numba's cache looked up for a module's kernels."""

import importlib
import sys

from clipclique.localization.firstrun import COMPILING, compile_note, kernels_cached


def test_a_module_s_kernels_are_cached_only_after_their_first_call(tmp_path, monkeypatch):
    (tmp_path / "tinykernels.py").write_text("from numba import njit\n\n\n@njit(cache=True)\n"
                                             "def twice(x):\n    return 2 * x\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("tinykernels")
    try:
        assert not kernels_cached(module)
        assert module.twice(21) == 42  # compiles, and writes the cache
        assert kernels_cached(module)
        assert list((tmp_path / "__pycache__").glob("tinykernels.twice-*.nbi"))
    finally:
        sys.modules.pop("tinykernels", None)


def test_a_module_without_cached_kernels_needs_no_note():
    assert kernels_cached(sys.modules[__name__])


def test_the_note_follows_the_clique_search_cache(monkeypatch):
    import clipclique.localization.firstrun as firstrun

    monkeypatch.setattr(firstrun, "kernels_cached", lambda module: False)
    assert compile_note() == COMPILING and "once" in COMPILING
    monkeypatch.setattr(firstrun, "kernels_cached", lambda module: True)
    assert compile_note() == ""
