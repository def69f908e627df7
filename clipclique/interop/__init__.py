"""Other systems' files in and out: object-SLAM maps (OA-SLAM, VOOM, GOReloc, MSG-Loc), detection
files (their JSON, COCO results with RLE masks), trajectories aligned to ground truth; read into and
written from this project's `Map` and `Detections`, one module per format or job.

Part of the library: it imports the core (types, mapfile, errors, safeio, yolo's COCO table), never
the tools, the runners or the simulation. What the readers accept is in docs/import_export.md
(the source formats' facts in docs/FORMATS.md). Every reader refuses a malformed file with one
`InteropError` line naming the file and the problem.
"""
