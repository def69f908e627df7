"""`clipclique-loc align MAP_A MAP_B`: the transform taking map A (the query map) into map B, on disk.

Writes, together or not at all (clipclique.io.outputs): alignment.json (every candidate: its 4 x 4
matrix from A's coordinates into B's, confidence, score, margin, residual, correspondences; whether
the answer is ambiguous and its competitors; how A's classes were matched to B's), alignment.g2o
(one `EDGE_SE3:QUAT 0 1 ...` line of the best candidate: vertex 0 is map B, vertex 1 map A; the
information matrix is described in `clipclique.multiframe.mapalign.g2o_edge`) and recording.rrd (both maps
overlaid).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clipclique.config import make_config
from clipclique.errors import ClipcliqueError
from clipclique.io.mapfile import load_map
from clipclique.io.outputs import Staging
from clipclique.multiframe.mapalign import MapAlignment, g2o_edge
from clipclique.pipeline import align_maps
from clipclique.types import Map

ALIGNMENT_FORMAT = "clipclique-loc alignment"
ALIGNMENT_VERSION = 1
ALIGN_DIR = Path("outputs/align")


@dataclass
class AlignSettings:
    query_map: Path  # MAP_A, aligned into ...
    map: Path  # ... MAP_B
    method: str = "clipclique"
    config_file: Path | None = None
    overrides: list[str] = field(default_factory=list)
    out: Path | None = None  # default outputs/align/<A>_into_<B>
    record: bool = True

    def out_dir(self) -> Path:
        return self.out or ALIGN_DIR / f"{_stem(self.query_map)}_into_{_stem(self.map)}"


def _stem(path: Path) -> str:
    return Path(path).name.removesuffix(".npz").removesuffix(".map")


def align_and_save(settings: AlignSettings) -> dict[str, Any]:
    """Align, then write alignment.json, alignment.g2o and (unless told not to) recording.rrd; the document."""
    config = make_config(settings.method, settings.config_file, settings.overrides)
    query, map = load_map(settings.query_map), load_map(settings.map)
    alignment = align_maps(query, map, config)
    document = alignment_document(settings, alignment, query, map)
    out_dir = settings.out_dir()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ClipcliqueError(f"--out {out_dir}: cannot create the folder ({error.strerror})") from None
    with Staging() as staging:
        texts = {"alignment.json": json.dumps(document, indent=1, allow_nan=False),
                 "alignment.g2o": "" if not alignment.candidates else
                 f"# vertex 0: {settings.map}, vertex 1: {settings.query_map}\n{document['g2o']}\n"}
        partials = {name: staging.path(out_dir / name) for name in texts}
        if settings.record:
            from clipclique.viz.align_recording import write_alignment_recording

            write_alignment_recording(staging.path(out_dir / "recording.rrd"), query, map, alignment,
                                      recording_description(document), d_adj=config.graph.d_adj)
        for name, text in texts.items():
            partials[name].write_text(text, encoding="utf-8")
        staging.commit()
    return document


def alignment_document(settings: AlignSettings, alignment: MapAlignment, query: Map, map: Map) -> dict[str, Any]:
    candidates = []
    for rank, candidate in enumerate(alignment.candidates, start=1):
        pairs = candidate.correspondences
        candidates.append({
            "rank": rank,
            "matrix": candidate.matrix().tolist(),
            "confidence": candidate.confidence,
            "score": candidate.score,
            "margin": candidate.margin,
            "rms_m": candidate.rms_m,
            "rotation_sigma_deg": candidate.rotation_sigma_deg,  # above 2.5 the candidate is never confident
            "correspondences": pairs.tolist(),
            "correspondence_classes": [[query.class_names[query.class_ids[a]], map.class_names[map.class_ids[b]]]
                                       for a, b in pairs],
        })
    return {
        "format": ALIGNMENT_FORMAT,
        "version": ALIGNMENT_VERSION,
        "query_map": str(settings.query_map),
        "map": str(settings.map),
        "direction": "each matrix takes query-map coordinates into map coordinates",
        "method": settings.method,
        "landmarks": {"query_map": len(query), "map": len(map)},
        "vocabulary": alignment.vocabulary,
        "ambiguous": alignment.ambiguous,
        "competitors": [index + 1 for index in alignment.competitors],
        "failure": None if alignment.failure is None else alignment.failure.message,
        "failure_kind": None if alignment.failure is None else alignment.failure.kind.value,
        "notes": alignment.notes,
        "candidates": candidates,
        "g2o": g2o_edge(alignment.candidates[0], query) if alignment.candidates else None,
    }


def recording_description(document: dict[str, Any]) -> str:
    lines = [f"# {document['query_map']} into {document['map']}",
             f"- landmarks: {document['landmarks']['query_map']} (query map), {document['landmarks']['map']} (map)",
             f"- ambiguous: {document['ambiguous']}" + (f" (competitors: ranks {document['competitors']})"
                                                        if document["ambiguous"] else "")]
    lines += [f"- candidate {c['rank']}: confidence {c['confidence']:.2f}, {len(c['correspondences'])} "
              f"correspondences, rms {c['rms_m']:.3f} m" for c in document["candidates"]]
    lines += [f"- note: {note}" for note in document["notes"]]
    return "\n".join(lines)
