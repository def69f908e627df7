"""Detectors, encoders and what a frame's detections become: observed ellipsoids and crops."""
