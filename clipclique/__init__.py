"""clipclique: object-based global localization of RGB-D frames (CLIP-Clique and baselines).

The public names (`Localizer`, `load_map`, `build_map`, `open_sequence`, `make_detector`, `load_encoder`) live in
clipclique.api and are imported on first use (PEP 562), so that `import clipclique` stays light: the compiled
kernels (numba) and open3d load only when a name that needs them is used."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from clipclique.version import __version__

__all__ = ["__version__", "Localizer", "build_map", "load_encoder", "load_map", "make_detector", "open_sequence"]

if TYPE_CHECKING:
    from clipclique.api import Localizer, build_map, load_encoder, load_map, make_detector, open_sequence


def __getattr__(name: str) -> Any:
    if name in __all__:
        from clipclique import api

        return getattr(api, name)
    raise AttributeError(f"module 'clipclique' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
