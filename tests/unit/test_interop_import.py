"""`clipclique-map import` and the files it would replace: another source's map is refused unless --force, the same
input imported again replaces its own output (the provenance's sha256)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clipclique.interop.errors import InteropError
from clipclique.io.mapfile import load_map
from clipclique.mapping.run import run_import

Q = " ".join(f"{v:.8f}" for v in np.diag([0.09, 0.01, 0.04, -1.0]).T.ravel())


def text_map(path, category: int = 41):
    path.write_text(f"1 {category} {Q}\n")
    return path


def test_import_refuses_another_sources_map_unless_forced(tmp_path):
    out = tmp_path / "maps" / "map_desk.map.npz"
    first, second = text_map(tmp_path / "goreloc.txt"), text_map(tmp_path / "voom.txt", 73)
    run_import(first, out=out, encoder_spec="none", rrd=False)
    digest = load_map(out).provenance["source"]["sha256"]
    assert len(digest) == 64 and load_map(out).class_names == ["cup"]
    run_import(first, out=out, encoder_spec="none", rrd=False)  # the same input: replaces its own output
    with pytest.raises(InteropError, match=rf"map_desk.map.npz holds a map imported from {tmp_path / 'goreloc.txt'}; "
                                           fr"importing {tmp_path / 'voom.txt'} would replace it: pass "
                                           r"--out FILE, or --force"):
        run_import(second, out=out, encoder_spec="none", rrd=False)
    assert load_map(out).class_names == ["cup"] and sorted(p.name for p in out.parent.iterdir()) == ["map_desk.map.npz"]
    run_import(second, out=out, encoder_spec="none", rrd=False, force=True)
    assert load_map(out).class_names == ["book"]


def test_import_refuses_to_replace_an_unreadable_file(tmp_path):
    out = tmp_path / "x.map.npz"
    out.write_bytes(b"not a map")
    with pytest.raises(InteropError, match="x.map.npz holds a file that is not a readable map"):
        run_import(text_map(tmp_path / "m.txt"), out=out, encoder_spec="none", rrd=False)
    assert out.read_bytes() == b"not a map"


def test_an_imported_maps_text_and_table_name_its_source_and_held_classes_only(tmp_path):
    """Before: 'from a import scene.', 'Left out as structure: .' and table rows (and a class count) for classes
    that only a class distribution names."""
    from rich.console import Console

    from clipclique.mapping.run import describe
    from clipclique.mapping.tables import print_import
    from tests.unit.test_interop_maps import msgloc_node

    path = tmp_path / "desk_map.json"
    path.write_text(json.dumps({"nodes": [msgloc_node(node_id=i, translation=[i * 0.4, 0, 2]) for i in range(3)]}))
    imported = run_import(path, out=tmp_path / "desk.map.npz", encoder_spec="none", rrd=False)
    map = imported.report.map
    assert map.class_names == ["keyboard", "mouse"] and set(map.class_ids.tolist()) == {0}
    text = describe(map, "desk_map.json")
    assert text.startswith(f"# Map of desk_map.json\n\n3 landmarks, 1 classes, imported from {path} (msgloc).")
    assert "structure" not in text
    console = Console(record=True, width=200)
    print_import(console, imported)
    printed = console.export_text()
    assert "3 landmarks, 1 classes" in printed and "mouse " not in printed
    assert "1 more classes appear only in the class distributions" in printed
