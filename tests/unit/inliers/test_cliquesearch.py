"""The branch-and-bound top-N clique search equals full enumeration (igraph) ranked by summed weight."""

import numpy as np
import pytest

from clipclique.inliers.cliquesearch import clique_total, top_cliques
from clipclique.inliers.compatibility import compatibility_graph
from clipclique.inliers.reference_cliques import maximal_cliques, rank_cliques


def reference(edges: np.ndarray, nodes: int, weights: np.ndarray, count: int, min_size: int = 3):
    cliques, cap = maximal_cliques(edges, nodes, min_size=min_size)
    assert cap is None
    ranked = rank_cliques(cliques, weights)[:count]
    return ranked, clique_total(ranked, weights)


def assert_same(found, ranked, totals):
    assert len(found.cliques) == len(ranked)
    for got, want in zip(found.cliques, ranked):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(found.totals, totals)
    for first in range(len(ranked) + 1):  # the stacked cliques the pose stage reads are the list's, the same values
        members, sizes = found.stacked(first)
        rest = ranked[first:]
        expected = np.concatenate(rest).astype(np.int64) if rest else np.zeros(0, np.int64)
        assert members.dtype == np.int64
        np.testing.assert_array_equal(members, expected)
        assert sizes.dtype == np.int64 and sizes.tolist() == [len(clique) for clique in rest]


@pytest.mark.parametrize("seed", range(6))
def test_random_graphs_give_the_enumerated_top_n_in_order(seed):
    rng = np.random.default_rng(seed)
    for _ in range(25):
        nodes = int(rng.integers(3, 70))
        upper = np.triu(rng.random((nodes, nodes)) < rng.uniform(0.05, 0.7), 1)
        edges = np.argwhere(upper)
        # half the graphs with few distinct weights: many ties, decided by the member lists
        weights = rng.choice([0.25, 0.5, 1.0], nodes) if seed % 2 else rng.random(nodes)
        count = int(rng.integers(1, 12))
        min_size = int(rng.integers(1, 5))
        found = top_cliques(edges, nodes, weights, count, min_size=min_size)
        assert_same(found, *reference(edges, nodes, weights, count, min_size))
        assert found.cap is None


def desk_compatibility(seed: int):
    """A dense desk-like problem: 45 landmarks within 2 m, 25 noisy observations of them, 3 to 4
    candidates per observation (several of one class), compatibility at d_comp = 0.3 m."""
    rng = np.random.default_rng(seed)
    landmarks = rng.uniform(0, 1, (45, 3)) * [2.0, 1.2, 0.5]
    seen = rng.choice(45, 25, replace=False)
    observed = landmarks[seen] + rng.normal(scale=0.05, size=(25, 3))
    extra = rng.integers(0, 45, (25, 3))
    candidates = np.unique(np.concatenate([np.column_stack((np.arange(25), seen))]
                                          + [np.column_stack((np.arange(25), extra[:, j])) for j in range(3)]), axis=0)
    scores = rng.choice([0.4, 0.6, 0.8, 1.0], len(candidates))
    return compatibility_graph(observed, landmarks, candidates, 0.3), candidates, scores


@pytest.mark.parametrize("seed", range(4))
def test_dense_desk_compatibility_graphs_give_the_enumerated_top_n(seed):
    edges, candidates, scores = desk_compatibility(seed)
    assert len(maximal_cliques(edges, len(candidates))[0]) > 200  # dense: many maximal cliques
    for count in (1, 5, 20):
        found = top_cliques(edges, len(candidates), scores, count, groups=candidates[:, 0])
        assert_same(found, *reference(edges, len(candidates), scores, count))
        assert found.reached < len(maximal_cliques(edges, len(candidates))[0])  # the bound cut the rest


def test_caps_are_reported():
    group = np.arange(21) // 3  # complement of 7 disjoint triangles: 3^7 maximal cliques, all of weight 7
    edges = np.argwhere(np.triu(group[:, None] != group[None, :], 1))
    found = top_cliques(edges, 21, np.ones(21), 5, max_cliques=50)
    assert found.cap == "max_cliques" and found.reached == 50 and len(found.cliques) == 5
    big = np.arange(30) // 3  # 3^10 cliques: more than one slice of the search, so the clock is read
    found = top_cliques(np.argwhere(np.triu(big[:, None] != big[None, :], 1)), 30, np.ones(30), 5, time_limit_s=0.0)
    assert found.cap == "time_limit" and 0 < found.reached < 3**10
    found = top_cliques(edges, 21, np.ones(21), 5)
    assert found.cap is None and found.reached == 3**7  # equal weights: nothing can be cut
    np.testing.assert_array_equal(found.cliques[0], [0, 3, 6, 9, 12, 15, 18])


def test_a_search_longer_than_its_first_slice_goes_on_in_the_arrays_it_began():
    """The first slice hands its arrays back only while the search runs on: the later slices must fill the same
    state and top list the caller reads (all 3^10 cliques of equal weight counted: more than one slice)."""
    big = np.arange(30) // 3
    edges = np.argwhere(np.triu(big[:, None] != big[None, :], 1))
    found = top_cliques(edges, 30, np.ones(30), 3, time_limit_s=60.0)
    assert found.cap is None and found.reached == 3**10
    np.testing.assert_array_equal(found.cliques[0], np.arange(0, 30, 3))
    np.testing.assert_array_equal(found.totals, [10.0, 10.0, 10.0])


def test_groups_must_be_independent():
    with pytest.raises(ValueError, match="one group"):
        top_cliques(np.array([[0, 1]]), 3, np.ones(3), 1, groups=np.array([0, 0, 1]))


def test_a_negative_group_is_refused_whether_or_not_a_search_runs():
    """The compiled search checks the groups itself (numpy's minimum was a tenth of a small search); a call that
    searches nothing (no clique wanted, fewer vertices than min_size) still refuses a negative group."""
    edges, weights = np.array([[0, 1], [1, 2], [0, 2]]), np.ones(3)
    for count, groups in [(5, np.array([0, -1, 2])), (0, np.array([0, -1, 2])), (5, np.array([-3, 1]))]:
        with pytest.raises(ValueError, match="groups must be non-negative"):
            top_cliques(edges if len(groups) == 3 else edges[:1], len(groups), weights[: len(groups)], count, groups)
    assert top_cliques(edges, 3, weights, 5, np.array([0, 1, 2])).sizes.tolist() == [3]


def test_the_bit_intrinsics_count_and_find_bits_as_python_does():
    """`_popcount` and `_lowest_bit` (LLVM's ctpop and cttz) on hand-made words: one bit at either end, all
    64, alternating patterns, and random words; `_popcount(0)` is 0."""
    from numba import njit

    from clipclique.inliers.cliquesearch import _lowest_bit, _popcount

    @njit
    def both(words):
        out = np.empty((len(words), 2), np.int64)
        for i in range(len(words)):
            out[i, 0] = _popcount(words[i])
            out[i, 1] = _lowest_bit(words[i]) if words[i] else -1
        return out

    rng = np.random.default_rng(2)
    words = [0, 1, 2, 3, 1 << 63, (1 << 64) - 1, 0x5555555555555555, 0xAAAAAAAAAAAAAAAA, 1 << 32, (1 << 32) - 1]
    words += [int(w) for w in rng.integers(0, 2**63, 40, dtype=np.uint64) << np.uint64(1)]
    got = both(np.array(words, np.uint64))
    assert got[:, 0].tolist() == [bin(w).count("1") for w in words]
    assert got[:, 1].tolist() == [(w & -w).bit_length() - 1 for w in words]


def test_each_clique_is_its_own_sorted_members_and_the_top_list_holds_the_heaviest_first():
    """The ranked list keeps its cliques in fixed rows (`Ranked.slot`): after many insertions before the
    last entry, each returned clique still holds its own members, sorted, and its total by `clique_total`."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        nodes = 30
        edges = np.array([(a, b) for a in range(nodes) for b in range(a + 1, nodes) if rng.random() < 0.5])
        weights = rng.random(nodes)
        found = top_cliques(edges, nodes, weights, 12)
        adjacent = {tuple(edge) for edge in edges.tolist()}
        assert len(found.cliques) == 12 and np.all(np.diff(found.totals) <= 0)
        for members, total in zip(found.cliques, found.totals):
            assert np.all(np.diff(members) > 0)
            assert all((a, b) in adjacent for i, a in enumerate(members.tolist()) for b in members[i + 1:].tolist())
        np.testing.assert_array_equal(clique_total(found.cliques, weights), found.totals)


def test_ranking_without_allocating_is_numbas_stable_argsort_of_the_negated_values():
    """`_rank_descending` against `np.argsort(-values, kind="mergesort")` compiled (what it replaced) on ties,
    -0 beside +0, NaN and infinities, and the empty case."""
    from numba import njit

    from clipclique.inliers.cliquesearch import _rank_descending

    @njit
    def both(values):
        rank = np.zeros(len(values), np.int64)
        _rank_descending(values, len(values), rank)
        return rank, np.argsort(-values, kind="mergesort")

    rng = np.random.default_rng(8)
    cases = [np.zeros(0), np.array([0.0, -0.0, 0.0, -0.0]), np.array([np.nan, 1.0, np.nan, 2.0, 1.0]),
             np.array([np.inf, -np.inf, np.nan, 0.5, np.inf]), np.ones(7)]
    cases += [rng.choice((0.0, -0.0, 0.25, 0.5, 1.0, np.nan), size) for size in rng.integers(1, 200, 60)]  # both sorts
    for values in cases:
        got, expected = both(values)
        assert got.tolist() == expected.tolist(), values


def plain_offers(cliques: list[list[int]], weights: np.ndarray, capacity: int) -> list[tuple[float, list[int]]]:
    """The ranked top list as `_offer` keeps it, in plain Python: each clique sorted, summed in that order from 0,
    inserted after every entry it does not rank before (heavier, or as heavy and lexicographically smaller; a NaN
    total ranks before nothing), the list cut at `capacity`."""
    ranked: list[tuple[float, list[int]]] = []

    def before(total, members, entry):
        if total != entry[0]:
            return total > entry[0]
        for mine, theirs in zip(members, entry[1]):
            if mine != theirs:
                return mine < theirs
        return len(members) < len(entry[1])

    for clique in cliques:
        members = sorted(clique)
        total = 0.0
        for member in members:
            total += weights[member]
        at = len(ranked)
        while at > 0 and before(total, members, ranked[at - 1]):
            at -= 1
        ranked.insert(at, (total, members))
        del ranked[capacity:]
    return ranked


def test_offer_keeps_the_plain_ranked_list():
    """`_offer` (its insertion sort and comparison written out) against the plain ranking: random cliques over few
    distinct weights (ties decided by the members, one clique a prefix of another, the same clique twice), -0 and
    NaN weights, capacities 1 to 6."""
    from clipclique.inliers.cliquesearch import FILLED, _offer

    rng = np.random.default_rng(8)
    for trial in range(300):
        weights = rng.choice([0.5, 1.0, -0.0, 0.25], 12)
        if trial % 5 == 0:
            weights[rng.integers(12)] = np.nan
        capacity = int(rng.integers(1, 7))
        cliques = [rng.choice(12, int(rng.integers(1, 6)), replace=False).tolist()
                   for _ in range(int(rng.integers(0, 15)))]
        cliques += [sorted(cliques[0])[:-1] or [0], cliques[0][::-1]] if cliques else []  # a prefix, the same again
        state = np.zeros(7, np.int64)
        total, size, slot, members = np.zeros(capacity), np.zeros(capacity, np.int64), np.arange(capacity), np.zeros(
            (capacity, 6), np.int64)
        for clique in cliques:
            scratch = np.array(clique + [0] * (6 - len(clique)), np.int64)
            _offer(scratch, len(clique), weights, state, total, size, slot, members)
        expected = plain_offers(cliques, weights, capacity)
        filled = int(state[FILLED])
        assert filled == len(expected)
        np.testing.assert_allclose(total[:filled], [entry[0] for entry in expected], rtol=1e-12, atol=1e-12)
        assert [members[slot[i], :size[i]].tolist() for i in range(filled)] == [entry[1] for entry in expected]


def test_the_stacked_top_list_is_the_rows_gathered():
    """`_stacked_best` against numpy's gather of the slot rows cut to their sizes: slots in any order, the list
    filled in part, wholly and not at all, -0 and NaN totals."""
    from clipclique.inliers.cliquesearch import Ranked, _stacked_best

    rng = np.random.default_rng(6)
    for trial in range(100):
        capacity, longest = int(rng.integers(1, 8)), int(rng.integers(1, 6))
        best = Ranked(rng.choice([1.5, -0.0, np.nan, 0.25], capacity), rng.integers(1, longest + 1, capacity),
                      rng.permutation(capacity), rng.integers(0, 99, (capacity, longest)))
        filled = int(rng.integers(0, capacity + 1))
        members, sizes, totals = _stacked_best(best, filled)
        rows = best.members[best.slot[:filled]]
        expected = rows[np.arange(longest) < best.size[:filled, None]]
        assert members.dtype == np.int64
        np.testing.assert_array_equal(members, expected)
        np.testing.assert_array_equal(sizes, best.size[:filled])
        np.testing.assert_array_equal(totals, best.total[:filled])  # copied, not computed
