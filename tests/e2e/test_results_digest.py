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
    ('demo', 'clipclique'): '8ae5fd6cf19bd4bb7cae68860ea35066dca6bdd56294f1376bc6cf9212755239',
    ('demo', 'sh'): '3a3a6145faad15f89194526f6cd51a318b99bc8e476b96b3fd7e8824d116c34e',
    ('demo', 'cliploc'): 'e0904adb6761c06cc7cbdcf5f6d4cbb2ddb3dd45a72b0dbb97e1efd5ec2b3cf7',
    ('demo_tum', 'clipclique'): 'eefb62add2cd6e23f9653a4d773ef5cb99f865adfa48b41578ff0cac8b2e0406',
    ('demo_tum', 'sh'): 'd8e43242a638cfe0e5cc776cd830cc98c94b07751ef0dec2d7ef46f4715bea6a',
    ('demo_tum', 'cliploc'): '8645fc860f43b97cc9b9a36adeb1c8e8ca2142d24a0c7a9fc95df9fbf888beb6',
    ('demo_apartment', 'clipclique'): 'f4274803511c3a480e8047bd4d5017a50ea26ede25db1ead2b6b669a64e348eb',
    ('demo_apartment', 'sh'): 'f06c21246245ee66d35d5b1d204a87888385a305e539dacdd952582a7d6d2b24',
    ('demo_apartment', 'cliploc'): '25e660fb552fea7c9b5d682aeba68205e57953abe302c16786de13844084989c',
    ('demo_desk', 'clipclique'): 'd86efd9e71318c23a3e3897429a4966dabcc4aaba8ee2f289be89f5b1d86c0cb',
    ('demo_desk', 'sh'): 'adcbc702f36cd4b0ffe4f88e900365082601d86174065a6cc0c63afba5771b84',
    ('demo_desk', 'cliploc'): '08ad75dfe77c2849b703b5510fa802c3539bda20acc37253bfb32817030fa529',
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
