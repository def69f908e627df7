"""More than one frame or map: windows fused by odometry, map-to-map alignment."""
