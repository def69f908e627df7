"""Beyond matching.max_candidates the clique search runs region by region (clipclique.inliers.regions): the same
ranked cliques as one search over the whole graph, copies of a room searched once, the cap per region."""

import numpy as np
import pytest

from clipclique.config import make_config
from clipclique.inliers import regions
from clipclique.inliers.cliquesearch import top_cliques
from clipclique.inliers.compatibility import compatibility_graph
from clipclique.outcomes import CapHit, RegionSplit
from clipclique.pipeline import index_map, localize
from clipclique.sim.synthetic import duplicate_rooms, synthetic_map, synthetic_query
from clipclique.types import Ellipsoids

ROOM = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])  # four landmarks, not in a plane
SCORES = np.array([0.9, 0.8, 0.7, 0.6])  # per observation, equal in every room
SETTINGS = make_config("clipclique").inliers


def building(rooms: int = 3, moved: float = 0.0):
    """`rooms` copies of ROOM 20 m apart along x (the last one's fourth landmark moved `moved` m along z), the
    room seen as it is, and each observation matched to its landmark in every room: rows (k, k + 4 r), grouped
    by observation."""
    landmarks = np.concatenate([ROOM + [20.0 * r, 0, 0] for r in range(rooms)])
    landmarks[-1, 2] += moved
    candidates = np.array([(k, k + 4 * r) for k in range(4) for r in range(rooms)])
    return ellipsoids(ROOM), ellipsoids(landmarks), candidates, SCORES[candidates[:, 0]], np.arange(4)


def ellipsoids(centers: np.ndarray) -> Ellipsoids:
    """Spheres of 0.2 m (seen whole: no slack) at `centers`."""
    return Ellipsoids(centers, np.full((len(centers), 3), 0.2), np.repeat(np.eye(3)[None], len(centers), 0))


def searched(observed, landmarks, candidates, scores, objects, count, max_candidates=100):
    split = regions.split(observed.centers, landmarks, candidates, scores, objects, SETTINGS, max_candidates)
    found, pairs_capped = regions.layouts(split, observed, landmarks, candidates[split.kept], scores[split.kept],
                                          objects, SETTINGS)
    assert not pairs_capped
    return split, found, regions.top_cliques(found, count, SETTINGS)


def whole(observed, landmarks, candidates, scores, count):
    """The one search over the whole compatibility graph the split must equal."""
    edges = compatibility_graph(observed.centers, landmarks.centers, candidates, SETTINGS.d_comp)
    return top_cliques(edges, len(candidates), scores, count, candidates[:, 0], SETTINGS.min_clique_size)


def test_region_labels_join_points_within_reach_numbered_by_first_point():
    points = np.array([[40, 0, 0], [0, 0, 0], [0.9, 0, 0], [41.5, 0, 0], [1.8, 0, 0], [20, 0, 0.0]])
    np.testing.assert_array_equal(regions.region_labels(points, 1.0), [0, 1, 1, 2, 1, 3])  # 0.9 apart join, 1.5 not
    np.testing.assert_array_equal(regions.region_labels(points, 2.0), [0, 1, 1, 0, 1, 2])
    # keys would overflow: one region (a coarser split loses no clique)
    np.testing.assert_array_equal(regions.region_labels(np.array([[0, 0, 0], [1e7, 1e7, 1e7]]), 1e-6), [0, 0])


def test_three_identical_rooms_are_one_layout_searched_once_and_ranked_by_rows():
    split, found, best = searched(*building(), count=2)
    assert [region.tolist() for region in split.rows] == [[0, 3, 6, 9], [1, 4, 7, 10], [2, 5, 8, 11]]
    assert split.copies == [[0, 1, 2]] and not split.capped and len(found) == 1
    assert [clique.tolist() for clique in best.cliques] == [[0, 3, 6, 9], [1, 4, 7, 10]]  # rooms 0 and 1: ties by rows
    assert best.totals.tolist() == [0.9 + 0.8 + 0.7 + 0.6] * 2 and best.reached == 3 and best.cap is None
    assert regions.summary(split, found, best) == RegionSplit(regions=3, layouts=1, tied_regions=3)


@pytest.mark.parametrize("count", [1, 2, 3, 5])
@pytest.mark.parametrize("moved", [0.0, 1.0])
def test_the_split_ranks_as_one_search_of_the_whole_graph(count, moved):
    observed, landmarks, candidates, scores, objects = building(moved=moved)
    split, found, best = searched(observed, landmarks, candidates, scores, objects, count)
    reference = whole(observed, landmarks, candidates, scores, count)
    assert [clique.tolist() for clique in best.cliques] == [clique.tolist() for clique in reference.cliques]
    np.testing.assert_array_equal(best.totals, reference.totals)
    assert len(found) == (2 if moved else 1)  # the room with a moved landmark is searched on its own


def test_a_moved_landmark_leaves_its_room_a_lighter_clique_and_two_tied_regions():
    split, found, best = searched(*building(moved=1.0), count=5)
    assert split.copies == [[0, 1], [2]]
    assert [clique.tolist() for clique in best.cliques] == [[0, 3, 6, 9], [1, 4, 7, 10], [2, 5, 8]]
    assert regions.summary(split, found, best).tied_regions == 2


def test_the_cap_is_counted_per_region():
    split, _, best = searched(*building(), count=3, max_candidates=3)
    assert split.capped and split.kept.tolist() == list(range(9))  # each room's worst (observation 3) dropped
    assert [region.tolist() for region in split.rows] == [[0, 3, 6], [1, 4, 7], [2, 5, 8]]
    assert [clique.tolist() for clique in best.cliques] == [[0, 3, 6], [1, 4, 7], [2, 5, 8]]


ROOM_MAP = synthetic_map(np.random.default_rng(0), num_landmarks=30)
ROOM_QUERY = synthetic_query(ROOM_MAP, np.random.default_rng(1))[0]  # seen in room 0


def in_six_rooms(jitter: float = 0.0, **overrides):
    """The query localized in six copies of ROOM_MAP 20 m apart (every landmark moved by up to `jitter` m)."""
    map = duplicate_rooms(ROOM_MAP, 6, gap=20.0)
    map.ellipsoids.centers[:] += np.random.default_rng(2).uniform(-jitter, jitter, map.ellipsoids.centers.shape)
    config = make_config("clipclique", overrides=overrides)
    return localize(ROOM_QUERY, index_map(map, config), config)


def test_a_building_beyond_the_cap_is_localized_without_a_cap_and_said_ambiguous():
    split = in_six_rooms(**{"matching.max_candidates": 20})
    free = in_six_rooms(**{"matching.max_candidates": 10_000_000})
    assert len(free.candidates) > 20 and free.cap_hit is None and free.region_split is None
    assert split.cap_hit is None and len(split.candidates) == len(free.candidates)
    assert split.region_split == RegionSplit(regions=6, layouts=1, tied_regions=6) and split.region_split.ambiguous
    assert any("ambiguous" in note for note in split.notes)
    assert len(split.hypotheses) == len(free.hypotheses) > 1
    for got, want in zip(split.hypotheses, free.hypotheses):
        np.testing.assert_array_equal(got.correspondences, want.correspondences)
        assert got.score == want.score
    rooms = {int(h.correspondences[0, 1]) // len(ROOM_MAP) for h in split.hypotheses}
    assert len(rooms) > 1  # the same fit in several rooms


def test_one_region_beyond_the_cap_is_capped_as_before():
    map = synthetic_map(np.random.default_rng(0), num_landmarks=60)
    observations, _ = synthetic_query(map, np.random.default_rng(1))
    config = make_config("clipclique", overrides={"matching.max_candidates": 6})
    result = localize(observations, index_map(map, config), config)
    assert result.cap_hit is CapHit.MAX_CANDIDATES and len(result.candidates) == 6 and result.region_split is None


def test_copies_whose_pair_test_is_a_close_call_are_tested_one_by_one():
    """Landmark 1 sits d_comp farther from landmark 0 than observation 1 from observation 0: that test is decided
    by round-off, which a copy's coordinates could round the other way."""
    observed, landmarks, candidates, scores, objects = building()
    centers = landmarks.centers.copy()
    centers[[1, 5, 9], 0] += SETTINGS.d_comp
    landmarks = ellipsoids(centers)
    split, found, best = searched(observed, landmarks, candidates, scores, objects, count=5)
    assert split.copies == [[0, 1, 2]] and [layout.vertices.shape[0] for layout in found] == [1, 1, 1]
    reference = whole(observed, landmarks, candidates, scores, 5)
    assert [clique.tolist() for clique in best.cliques] == [clique.tolist() for clique in reference.cliques]
    # room 2's coordinates (40 m along) round that test the other way: one copy of three keeps all four landmarks
    assert best.cliques[0].tolist() == [2, 5, 8, 11] and len(best.cliques[1]) == 3


def test_many_candidates_in_several_regions_are_split_below_the_cap_with_the_same_hypotheses():
    split = in_six_rooms(**{"inliers.region_split_from": 20})
    whole_map = in_six_rooms(**{"inliers.region_split_from": 1_000_000})
    assert split.region_split is not None and whole_map.region_split is None and split.cap_hit is None
    assert [h.correspondences.tolist() for h in split.hypotheses] == [h.correspondences.tolist()
                                                                       for h in whole_map.hypotheses]
    assert [h.score for h in split.hypotheses] == [h.score for h in whole_map.hypotheses]


def test_rooms_that_differ_are_searched_as_one_map_and_capped_as_before():
    """Six rooms a centimetre apart from each other's layout: six layouts, no copy to search once, so the split
    would cost six graphs and searches for nothing; the whole map is searched, its cap as before."""
    split = in_six_rooms(jitter=0.01, **{"inliers.region_split_from": 20})
    capped = in_six_rooms(jitter=0.01, **{"matching.max_candidates": 20})
    assert split.region_split is None and split.cap_hit is None
    assert capped.region_split is None and capped.cap_hit is CapHit.MAX_CANDIDATES and len(capped.candidates) == 20
