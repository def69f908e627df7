"""The public names (clipclique.api): the short example works on the demo, gives what the pipeline gives, and
`import clipclique` stays light."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import clipclique
from clipclique.errors import ClipcliqueError, MapFileError
from clipclique.pose.distance import pose_errors


@pytest.fixture(scope="module")
def demo(demo_data, tmp_path_factory) -> tuple[Path, Path]:
    """A data root holding a 4-frame full-size demo scene, and its map (simulated CLIP) built through the api."""
    root = demo_data("demo", size=None)
    map_path = tmp_path_factory.mktemp("api-map") / "demo.map.npz"
    clipclique.build_map("demo", data_root=root, out=map_path)
    return root, map_path


def test_the_short_example_localizes_the_demo(demo):
    root, map_path = demo
    sequence = clipclique.open_sequence("demo", root)
    localizer = clipclique.Localizer(map_path, sequence=sequence)
    errors = [pose_errors(localizer.localize(sequence[i]).hypotheses[0].pose, sequence[i].pose) for i in range(3)]
    assert (localizer.detector.name, localizer.encoder.name) == ("simulated", "simulated-clip")  # the CLI's defaults
    assert all(te < 0.5 and re < 0.25 for te, re in errors), errors  # measured: 0.34/0.45/0.19 m, 0.12/0.21/0.10 rad


def test_the_library_page_example_prints_a_pose(demo, repository, tmp_path):
    """docs/library.md's first python block, as written, in a folder holding outputs/maps/demo.map.npz."""
    root, map_path = demo
    page = (repository / "docs" / "library.md").read_text()
    example = re.search(r"^```python\n(.*?)^```", page, re.MULTILINE | re.DOTALL).group(1)
    assert len(example.strip().splitlines()) <= 10
    (tmp_path / "outputs" / "maps").mkdir(parents=True)
    shutil.copy(map_path, tmp_path / "outputs" / "maps" / "demo.map.npz")
    env = os.environ | {"CLIPCLIQUE_DATA": str(root), "PYTHONPATH": str(repository)}
    out = subprocess.run([sys.executable, "-c", example], cwd=tmp_path, env=env, capture_output=True, text=True,
                         check=True).stdout
    assert out.startswith("pose (camera to world):\n") and len(out.splitlines()) == 5, out


def test_the_localizer_gives_what_the_pipeline_gives(demo):
    """Same frame, same detector and encoder by hand: the pipeline's ranked poses, identical (one process, one path)."""
    from clipclique.config import make_config
    from clipclique.perception.observations import embed, extract_observations
    from clipclique.pipeline import index_map, localize

    root, map_path = demo
    sequence = clipclique.open_sequence("demo", root)
    map = clipclique.load_map(map_path)
    detector = clipclique.make_detector("simulated", sequence, map)
    encoder = clipclique.load_encoder("simulated", sequence)
    config = make_config("clipclique", None, ["inliers.d_comp=0.4"])
    frame = sequence[1]
    observations = embed(extract_observations(frame, detector.detect(frame), config.observations), encoder)
    expected = localize(observations, index_map(map, config), config)
    localizer = clipclique.Localizer(map, detector="simulated", encoder=encoder, overrides=["inliers.d_comp=0.4"],
                                     sequence=sequence)
    for result in (localizer.localize(frame), localizer.localize_observations(observations)):
        assert len(result.hypotheses) == len(expected.hypotheses) > 0
        for got, want in zip(result.hypotheses, expected.hypotheses):
            assert np.array_equal(got.pose.matrix(), want.pose.matrix())
        assert np.array_equal(result.candidates, expected.candidates)


def test_a_method_without_clip_loads_no_encoder(demo):
    root, map_path = demo
    localizer = clipclique.Localizer(map_path, method="sh", encoder="simulated")
    assert localizer.encoder is None and localizer.notes == [
        "--encoder simulated not used: the sh descriptor does not read CLIP"]


def test_refusals_name_what_is_missing(demo, tmp_path):
    root, map_path = demo
    sequence = clipclique.open_sequence("demo", root)
    with pytest.raises(ClipcliqueError, match="no detector; pass detector= or sequence="):
        clipclique.Localizer(map_path).localize(sequence[0])
    with pytest.raises(MapFileError, match="nothing.map.npz"):
        clipclique.Localizer(tmp_path / "nothing.map.npz")
    with pytest.raises(ClipcliqueError, match="pass sequence="):
        clipclique.Localizer(map_path, detector="gt")


def test_import_clipclique_loads_neither_numba_nor_open3d():
    code = ("import sys, clipclique; heavy = [m for m in ('numba', 'open3d', 'clipclique.api') if m in sys.modules]; "
            "names = dir(clipclique); "
            "print(heavy, set(clipclique.__all__) <= set(names), len(names) == len(set(names)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[] True True"
    with pytest.raises(AttributeError, match="no attribute 'Localiser'"):
        clipclique.Localiser  # noqa: B018
