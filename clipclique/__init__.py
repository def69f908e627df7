"""clipclique: object-based global localization of RGB-D frames (CLIP-Clique and baselines)."""

__version__ = "0.1.0"
