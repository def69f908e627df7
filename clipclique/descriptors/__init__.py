"""What makes an observation and a landmark alike: graph descriptors, similarity, look-alike classes, adaptive
matching."""
