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

# (scene, method) -> sha256 of the canonical outcome of every frame
EXPECTED = {
    ('demo', 'clipclique'): '8da611850949ad54f9c635c86a62981b6f4a15dd9d05e85bc803c2856b1c3f96',
    ('demo', 'sh'): '8c8efc539f617ff72db0365183c875c255c892b62e3712a84c5d0f9acf37b6de',
    ('demo', 'cliploc'): '3ea921293186fb0081366456683b0a4af63fcd5d47e75d0100bb7c0e80641bee',
    ('demo_tum', 'clipclique'): '71e604e956da5eb8f1c0c2646f24e268c6ef11629e3c830f3293e13f8d92d2d0',
    ('demo_tum', 'sh'): 'd00095ded048d884b4b45901d91fa44fc1291c596611d511469b25fcae1ab3f3',
    ('demo_tum', 'cliploc'): '7c52ac866549fb1dc3b1e42b27b387b0fe114678f4c09912f03ccea1fdf89a93',
    ('demo_apartment', 'clipclique'): '258897efa173f0581b6f6933841d8b35597439c8f5b9cfdb40de067fd6563011',
    ('demo_apartment', 'sh'): '03c56e0134714fa6fad3d5ece0227496bef33399be9ddd23ab27ed6a9748add8',
    ('demo_apartment', 'cliploc'): 'c9882ce04158329075aa2796693cbd49779428e4adf6ae04da8035e25432f1dc',
    ('demo_desk', 'clipclique'): '35e33ae102f12e53cac522af00e2d3d2480170efdfb69f03aa10ae436276c6eb',
    ('demo_desk', 'sh'): '6d78133ee9e45a90a64e45eb3982d85c0d0029e74dcf5accba819e774992ca63',
    ('demo_desk', 'cliploc'): 'd9c74cbb3b78ece3fee5c66f4c096c75383d66a53eff351a773e187c0c2156cf',
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
