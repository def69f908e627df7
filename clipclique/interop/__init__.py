"""Other systems' files, in and out: object maps and detections as object-SLAM systems write them
(OA-SLAM, VOOM, ...; their formats in docs/FORMATS.md), read into and written from this project's
`Map` and `Detections`. One module per format. Part of the library: it imports the core
(types, mapfile, errors, safeio), never the tools, the runners or the simulation.
"""
