"""Poses from correspondences: the weighted fits, their conditioning, refinement, the stacked pool."""
