"""clipclique.benchmark.accuracy_levers: `--view` keeps the frames of the view suite.view_of names (issue 37's sparse
views: 3-5 distinct mapped objects observed), `--candidates` counts what the candidates lack, `--changed-from` the
frames a lever moves."""

from __future__ import annotations

import numpy as np

from clipclique.benchmark import accuracy_levers, suite
from clipclique.benchmark.accuracy_levers import Missing, changed
from clipclique.benchmark.suite import CachedFrame, CachedSequence, in_view, view_of
from clipclique.outcomes import LocalizationResult
from clipclique.types import Ellipsoids, Map, Observations, Pose


def landmarks(count: int = 8) -> Map:
    """`count` landmarks 1 m apart on a line, instance ids 10, 11, ..."""
    centers = np.stack([np.arange(count, dtype=float), np.zeros(count), np.full(count, 3.0)], axis=1)
    return Map(Ellipsoids(centers, np.full((count, 3), 0.2), np.tile(np.eye(3), (count, 1, 1))),
               np.arange(count) % 3, ["cup", "book", "chair"], [f"object {i}" for i in range(count)],
               np.arange(10, 10 + count))


def seen(*instance_ids: int) -> Observations:
    """Observations of these ground-truth instances (-1 unknown), one each, where the map has them."""
    ids = np.array(instance_ids, int)
    centers = np.stack([np.maximum(ids - 10, 0).astype(float), np.zeros(len(ids)), np.full(len(ids), 3.0)], axis=1)
    return Observations(Ellipsoids(centers, np.full((len(ids), 3), 0.2), np.tile(np.eye(3), (len(ids), 1, 1))),
                        np.maximum(ids - 10, 0) % 3, None, ids, np.arange(len(ids)))


# A short slice: (instance ids observed, its view by the definition: distinct mapped objects, 3-5 sparse)
SLICE = [
    ((10, 11), "few"),
    ((10, 11, 12), "sparse"),
    ((10, 10, 11), "few"),  # a second detection of one object is not another object
    ((10, 11, 12, -1, 99), "sparse"),  # a false positive (-1) and an unmapped object (99) are none
    ((10, 11, 12, 13, 14), "sparse"),
    ((10, 11, 12, 13, 14, 15), "busy"),
    ((10, 11, 12, 12, 13), "sparse"),
    ((), "few"),
]


def sequence() -> CachedSequence:
    frames = [CachedFrame(i, seen(*ids), Pose.identity()) for i, (ids, _) in enumerate(SLICE)]
    return CachedSequence("slice", landmarks(), frames, {}, {}, None)


def test_the_view_is_the_distinct_mapped_objects_observed():
    map = landmarks()
    assert suite.SPARSE_VIEW_OBJECTS == (3, 5)
    assert [view_of(seen(*ids), map) for ids, _ in SLICE] == [view for _, view in SLICE]


def test_a_view_keeps_exactly_its_frames_in_order():
    whole = sequence()
    for view in ("sparse", "busy", "few"):
        kept = in_view(whole, view)
        assert [f.index for f in kept.frames] == [i for i, (_, v) in enumerate(SLICE) if v == view]
        assert kept.map is whole.map
    assert in_view(whole, "all") is whole
    assert len(whole.frames) == len(SLICE)  # the whole sequence is left as it was


def result(candidates: list[tuple[int, int]]) -> LocalizationResult:
    pairs = np.array(candidates, int).reshape(-1, 2)
    return LocalizationResult(hypotheses=[], candidates=pairs, candidate_scores=np.ones(len(pairs)),
                              similarity=np.zeros((0, 0)), num_cliques=0, cap_hit=None, failure=None)


def test_missing_counts_the_right_pairs_among_the_candidates():
    map = landmarks()
    observations = seen(10, 11, 12, -1)  # landmarks 0, 1, 2 and a false positive
    right = suite.mapped_pairs(observations, map)
    missing = Missing()
    missing.add(result([(0, 0), (1, 1), (2, 2), (3, 4)]), right)  # all three right: not short
    missing.add(result([(0, 0), (0, 1), (1, 0), (2, 5)]), right)  # only observation 0's own: short, 2 unmatched
    missing.add(result([]), right)  # none: short, 3 unmatched
    assert (missing.frames, missing.short_frames, missing.mapped, missing.unmatched) == (3, 2, 9, 5)
    assert missing.cells() == " 2 of 3 | 55.6% |"


def test_changed_frames_move_by_more_than_a_centimetre_or_gain_or_lose_a_pose():
    base = [0.1, 0.1, None, 2.0, None]
    assert changed([0.1, 0.105, None, 2.0, None], base) == 0
    assert changed([0.3, 0.1, 1.0, 2.0, None], base) == 2
    assert changed([0.1, None, None, 2.0, 0.2], base) == 2


def test_view_sparse_scores_only_the_sparse_frames(monkeypatch, capsys):
    whole = sequence()
    monkeypatch.setattr(suite, "ensure_map", lambda scene, root: None)
    monkeypatch.setattr(suite, "cache_sequence", lambda scene, root, frames, tick: whole)
    assert accuracy_levers.main(["--scenes", "slice", "--view", "sparse", "--levers", "before",
                                 "--candidates"]) == 0
    captured = capsys.readouterr()
    assert "slice: 4 frames of view sparse" in captured.err
    rows = [line for line in captured.out.splitlines() if line.startswith("| slice |")]
    assert len(rows) == 1 and rows[0].startswith("| slice | SH | before |")  # no CLIP: the map has no texts
    assert rows[0].split("|")[-3].strip().endswith("of 4")  # the candidates' column counts the 4 sparse frames


def test_a_view_without_frames_prints_no_rows(monkeypatch, capsys):
    few = CachedSequence("slice", landmarks(), [CachedFrame(0, seen(10, 11), Pose.identity())], {}, {}, None)
    monkeypatch.setattr(suite, "ensure_map", lambda scene, root: None)
    monkeypatch.setattr(suite, "cache_sequence", lambda scene, root, frames, tick: few)
    assert accuracy_levers.main(["--scenes", "slice", "--view", "busy", "--levers", "before"]) == 0
    captured = capsys.readouterr()
    assert "slice: 0 frames of view busy" in captured.err and "| slice |" not in captured.out
