"""Whether this run will first compile the localization kernels: numba compiles each `@njit(cache=True)` kernel
on its first use after an install and keeps it in an on-disk cache, so a fresh install's first run spends about
a minute (on 2 cores) before its first frame, silently unless the progress bar says why."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

COMPILING = "compiling the kernels, once after an install (about a minute)"


def kernels_cached(module: ModuleType) -> bool:
    """Whether numba's cache holds any kernel of `module`; True where numba keeps no cache file to look for."""
    for value in vars(module).values():
        folder = getattr(getattr(value, "_cache", None), "cache_path", None)  # a cached numba dispatcher's
        if folder is not None:
            return any(Path(folder).glob(f"{module.__name__.rpartition('.')[2]}.*.nbi"))
    return True


def compile_note() -> str:
    """What the progress bar says before the first frame: COMPILING when the clique search (every run's) is not
    in the cache yet, else nothing."""
    from clipclique.inliers import cliquesearch

    return "" if kernels_cached(cliquesearch) else COMPILING
