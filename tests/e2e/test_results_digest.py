"""Results to the bit: every pose, correspondence, score, confidence and failure of full runs on the
four generated scenes, held as one digest per run (timings and paths left out).

A refactoring must leave these digests alone. A change that moves results on purpose re-baselines
them in the same commit and says which figures moved (`python -m pytest tests/e2e/test_results_digest.py
--digests` prints the new values)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

from clipclique.resolve import open_scene
from clipclique.backends import load_encoder
from clipclique.mapfile import save_map
from localization.results import read_results
from localization.run import RunSettings, run_and_save
from mapping.build import build_map

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]  # the repository

# (scene, method) -> sha256 of the canonical outcome of every frame, under the pinned arithmetic
# (clipclique.arithmetic: OpenBLAS's Haswell kernels and numpy's loops up to x86-64-v3, which tests/conftest.py
# sets on any x86-64 machine with AVX2 and FMA)
EXPECTED = {
    ('demo', 'clipclique'): 'a10c315a5962fe56a0c4f912595e6fbc77ab4e133984f638c2b42b08e915a05c',
    ('demo', 'sh'): 'e099af79679e35f5da0cbcc9bac9f8714a89548b4336fbbee46ff54e5d4658c8',
    ('demo', 'cliploc'): '0c1227454851021bbffa6c54f9ee7df7418694cbaf75b177ea002a65fb284826',
    ('demo_tum', 'clipclique'): '394982af8cf2b076bc2f0f06f2ad3b07b679e3390d77a4d59d75c08d0764f3b9',
    ('demo_tum', 'sh'): 'feebb229fa9f557ccc752c58f4fa1dc5f5c21b9fbaa1579c9246665d21a84b7a',
    ('demo_tum', 'cliploc'): 'e7f74631223afe1c8ae8671cb8424fdd0e9f27bcb0be8315b7d33c424b2de543',
    ('demo_apartment', 'clipclique'): '3b21e5fbd04e7788adaeaf2f47947dd70d44173186983090a86d1cb7f6d2ad8f',
    ('demo_apartment', 'sh'): 'c50e127681980c25291c59fac7780f9ce91db266cba2b6775964aff11a4e596e',
    ('demo_apartment', 'cliploc'): '5423bb1c48da010dd4e4ca9931610332619d79264ad8fc6d7916f2240931a0da',
    ('demo_desk', 'clipclique'): '93c1c4d71f639e89de842be4abef7187bde26a2349acd60a6a08585e7efc7287',
    ('demo_desk', 'sh'): '4489b2f11c884a536ce2872051356e667074c80a11ee0f5b4f9ce823ad97c698',
    ('demo_desk', 'cliploc'): '9f8d582689b742777a838e8b2b08329410b96f49fccf386bb3f24ef59c06d015',
}


def canonical(document: dict[str, Any]) -> list[dict[str, Any]]:
    """What a run decided, frame by frame, without timings, paths or wording of notes."""
    frames = []
    for frame in document["frames"]:
        evaluation = frame["evaluation"]
        frames.append({
            "index": frame["index"],
            "detections": frame["detections"],
            "observations": frame["observations"],
            "candidates": frame["candidates"],
            "num_cliques": frame["num_cliques"],
            "failure": frame["failure"],
            "hypotheses": [{key: hypothesis[key] for key in ("score", "conditioning", "verification", "confidence",
                                                             "pose", "correspondences")}
                           for hypothesis in frame["hypotheses"]],
            "evaluation": {key: evaluation[key] for key in ("translation_error_m", "rotation_error_deg", "precision",
                                                            "recall")},
        })
    return frames


def digest(document: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(canonical(document), sort_keys=True).encode()).hexdigest()


RUNS = [(scene, method) for scene in ("demo", "demo_tum", "demo_apartment", "demo_desk")
        for method in ("clipclique", "sh", "cliploc")]


@pytest.fixture(scope="module")
def maps(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("maps")
    encoder = load_encoder("simulated")
    paths = {}
    for scene in sorted({scene for scene, _ in RUNS}):
        map, _ = build_map(open_scene(scene, ROOT / "data"), encoder)
        paths[scene] = folder / f"{scene}.map.npz"
        save_map(map, paths[scene])
    return paths


@pytest.mark.parametrize(("scene", "method"), RUNS)
def test_results_are_identical_to_the_baseline(maps, tmp_path, scene, method, request):
    out = tmp_path / "run"
    run_and_save(RunSettings(scene, method, map_path=maps[scene], data_root=ROOT / "data", out=out, record=False))
    found = digest(read_results(out / "results.json"))
    if request.config.getoption("--digests"):
        print(f"\n    ({scene!r}, {method!r}): {found!r},")
    assert found == EXPECTED[scene, method]
