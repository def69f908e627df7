"""Poses from correspondences: the weighted fits, their conditioning, refinement, the stacked pool; distance: how
far one pose is from another."""
