"""Which correspondences agree: the compatibility graph, the clique search, regions, RANSAC/PROSAC."""
