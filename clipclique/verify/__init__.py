"""Whether a pose explains the image: projection, verification, calibrated confidence."""
