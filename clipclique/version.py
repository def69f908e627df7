"""The package's version, in a module of its own: the map writers stamp it without importing the package root
(which re-exports clipclique.api, the top layer)."""

__version__ = "0.1.0"
