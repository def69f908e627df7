"""The warm-up's stale-cache check: numba checks a cached kernel against its own file only."""

import os

from tests.warm_up import stale_kernels


def test_a_kernel_cache_older_than_a_module_it_reaches_is_stale(tmp_path):
    for name in ("fit", "refine", "other"):
        (tmp_path / f"{name}.py").write_text("from numba import njit\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    files = {name: cache / f"{name}.kernel-12.py311{suffix}" for name, suffix in
             (("refine", ".nbi"), ("other", ".1.nbc"))}
    for file in files.values():
        file.write_bytes(b"")
    modules = {name: tmp_path / f"{name}.py" for name in ("fit", "refine", "other")}
    imported = {"refine": {"stack"}, "stack": {"fit"}, "other": set()}  # refine reaches fit through stack
    modules["stack"] = tmp_path / "stack.py"
    modules["stack"].write_text("")  # no kernels: its edits cannot stale a cache
    for path in [*modules.values(), *files.values()]:
        os.utime(path, (1000, 1000))
    assert stale_kernels(modules, imported) == []
    os.utime(modules["fit"], (2000, 2000))  # fit.py edited after refine's kernels were cached
    assert stale_kernels(modules, imported) == [files["refine"]]
    os.utime(files["refine"], (3000, 3000))  # ... and compiled again since
    assert stale_kernels(modules, imported) == []
    os.utime(modules["stack"], (4000, 4000))
    assert stale_kernels(modules, imported) == []
