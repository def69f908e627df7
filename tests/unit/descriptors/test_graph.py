import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import cKDTree

from clipclique.descriptors.graph import (
    capped_semantic_graph,
    landmark_histograms,
    query_histograms,
    random_walk_descriptors,
    semantic_graph,
    semantic_histograms,
)

A, B, C = 0, 1, 2
# Hand-drawn graph: triangle 0-1-2, tail 2-3, node 4 far away. Classes A B A C B.
CENTERS = np.array([[0, 0, 0], [0.5, 0, 0], [0.25, 0.4, 0], [0.25, 1.1, 0], [5, 5, 5.0]])
CLASSES = np.array([A, B, A, C, B])


def bin_of(*labels):
    return labels[0] * 9 + labels[1] * 3 + labels[2]


def test_semantic_graph_joins_centres_closer_than_d_adj():
    adjacency = semantic_graph(CENTERS, 0.8).toarray()
    expected = {(0, 1), (0, 2), (1, 2), (2, 3)}
    assert {(i, j) for i, j in np.argwhere(adjacency) if i < j} == expected
    assert (adjacency == adjacency.T).all()


def test_semantic_graph_boundary_is_strict():
    adjacency = semantic_graph(np.array([[0, 0, 0], [0.5, 0, 0.0]]), 0.5)
    assert adjacency.nnz == 0


def test_semantic_histograms_equal_hand_counted_walks():
    histograms = semantic_histograms(semantic_graph(CENTERS, 0.8), CLASSES, num_classes=3).toarray()
    expected = np.zeros((5, 27))
    # node 0: 0-1-0 ABA, 0-1-2 ABA, 0-2-0 AAA, 0-2-1 AAB, 0-2-3 AAC
    expected[0, [bin_of(A, B, A), bin_of(A, A, A), bin_of(A, A, B), bin_of(A, A, C)]] = [2, 1, 1, 1]
    # node 1: 1-0-1 BAB, 1-0-2 BAA, 1-2-0 BAA, 1-2-1 BAB, 1-2-3 BAC
    expected[1, [bin_of(B, A, B), bin_of(B, A, A), bin_of(B, A, C)]] = [2, 2, 1]
    # node 2: 2-0-1 AAB, 2-0-2 AAA, 2-1-0 ABA, 2-1-2 ABA, 2-3-2 ACA
    expected[2, [bin_of(A, A, B), bin_of(A, A, A), bin_of(A, B, A), bin_of(A, C, A)]] = [1, 1, 2, 1]
    # node 3: 3-2-0 CAA, 3-2-1 CAB, 3-2-3 CAC; node 4 is isolated: no walk, zero histogram
    expected[3, [bin_of(C, A, A), bin_of(C, A, B), bin_of(C, A, C)]] = [1, 1, 1]
    norms = np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(histograms, np.divide(expected, norms, where=norms > 0, out=np.zeros_like(expected)))
    np.testing.assert_allclose(np.linalg.norm(histograms[:4], axis=1), 1.0)


def test_histograms_are_sparse_for_large_vocabularies():
    rng = np.random.default_rng(0)
    centers = rng.uniform(0, 4, size=(200, 3))
    histograms = semantic_histograms(semantic_graph(centers, 0.8), rng.integers(0, 40, 200), num_classes=40)
    assert histograms.shape == (200, 64_000)
    assert histograms.format == "csr" and histograms.nnz < 0.001 * 200 * 64_000


@pytest.mark.parametrize("length", [1, 2, 4])
def test_walk_length_sets_the_number_of_bins(length):
    histograms = semantic_histograms(semantic_graph(CENTERS, 0.8), CLASSES, 3, walk_length=length)
    assert histograms.shape == (5, 3**length)


def test_random_walks_follow_edges_and_are_seeded():
    adjacency = semantic_graph(CENTERS, 0.8)
    counts = random_walk_descriptors(adjacency, CLASSES, 3, 3, walks=50, rng=np.random.default_rng(1)).toarray()
    again = random_walk_descriptors(adjacency, CLASSES, 3, 3, walks=50, rng=np.random.default_rng(1)).toarray()
    np.testing.assert_array_equal(counts, again)
    np.testing.assert_array_equal(counts.sum(axis=1), 50)
    hand = semantic_histograms(adjacency, CLASSES, 3).toarray()
    assert ((counts[:4] > 0) <= (hand[:4] > 0)).all()  # every random walk is one of the walks counted by hand
    assert counts[3, bin_of(C, A, C)] > 0 and counts[3, bin_of(C, A, A)] > 0
    assert counts[4, bin_of(B, B, B)] == 50  # an isolated node stays on itself


def test_histograms_equal_walk_enumeration_of_the_literal_reference():
    from clipclique.benchmark import literal_reference

    rng = np.random.default_rng(5)
    centers = rng.uniform(0, 2.5, size=(60, 3))
    classes = rng.integers(0, 7, 60)
    ours = semantic_histograms(semantic_graph(centers, 0.8), classes, 7).toarray()
    for node, counts in enumerate(literal_reference.semantic_histograms(centers, classes, 0.8)):
        expected = np.zeros(7**3)
        for (a, b, c), count in counts.items():
            expected[a * 49 + b * 7 + c] = count
        norm = np.linalg.norm(expected)
        np.testing.assert_allclose(ours[node], expected / norm if norm else expected, atol=1e-12)


def test_degree_cap_keeps_real_graphs_and_bounds_degenerate_ones():
    rng = np.random.default_rng(2)
    desk = rng.normal(0, 0.5, size=(47, 3))  # a cluttered desk: degree up to ~30
    assert (semantic_graph(desk, 0.8, max_degree=64) != semantic_graph(desk, 0.8)).nnz == 0
    assert capped_semantic_graph(desk, 0.8, max_degree=64).capped_nodes == 0
    pile = np.zeros((3000, 3))  # 3,000 landmarks in one spot: 4.5 million edges uncapped
    capped = semantic_graph(pile, 0.8, max_degree=16)
    degree = np.diff(capped.indptr)
    assert degree.max() <= 16 and (capped != capped.T).nnz == 0 and capped.diagonal().sum() == 0
    assert capped_semantic_graph(pile, 0.8, max_degree=16).capped_nodes == 3000
    near = semantic_graph(desk, 0.8, max_degree=3)
    for node in range(47):  # what a node keeps are among its 3 nearest
        nearest = set(np.argsort(np.linalg.norm(desk - desk[node], axis=1))[1:4].tolist())
        assert set(near[node].indices.tolist()) <= nearest


def knn_capped_graph(centers, d_adj, max_degree):
    """What `capped_semantic_graph` replaced: every node's k-nearest query, the mutual edges by scipy's
    elementwise product, and the capped count from a second KD-tree's ball query."""
    n = len(centers)
    if n == 0:
        return sp.csr_matrix((0, 0), dtype=bool), 0
    k = min(max_degree + 1, n)
    distances, neighbours = cKDTree(centers).query(centers, k=k, distance_upper_bound=d_adj)
    distances, neighbours = distances.reshape(n, k), neighbours.reshape(n, k)
    rows = np.repeat(np.arange(n), k)
    keep = (distances.ravel() < d_adj) & (neighbours.ravel() != rows)
    kept = sp.csr_matrix((np.ones(keep.sum(), dtype=bool), (rows[keep], neighbours.ravel()[keep])), shape=(n, n))
    adjacency = kept.multiply(kept.T).tocsr().astype(bool)
    within = cKDTree(centers).query_ball_point(centers, d_adj, return_length=True) - 1
    return adjacency, int(np.count_nonzero(within > np.diff(adjacency.indptr)))


def assert_same_csr(got, expected):
    assert got.shape == expected.shape
    for name in ("indptr", "indices", "data"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
        assert getattr(got, name).dtype == getattr(expected, name).dtype


@pytest.mark.parametrize("centers, d_adj, max_degree, capped", [
    (np.zeros((0, 3)), 0.8, 64, 0),  # empty map
    (np.array([[0, 0, 0.0]]), 0.8, 64, 0),  # one isolated node
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [3, 0, 0.0]]), 1.0, 64, 3),  # distance exactly d_adj: no edge, capped
    (np.array([[0, 0, 0], [0.5, 0, 0], [0.5, 0, 0], [9, 9, 9.0]]), 0.8, 1, 3),  # duplicates, cap of one, isolated
    (np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [0.4, 0, 0], [0.45, 0, 0.0]]), 0.8, 2, 6),  # a line
    (np.zeros((40, 3)), 0.8, 64, 0),  # a pile under the cap
    (np.zeros((40, 3)), 0.8, 5, 40),  # a pile over it
])
def test_capped_graph_is_the_knn_graph_and_ball_count_on_hand_made_maps(centers, d_adj, max_degree, capped):
    expected, expected_capped = knn_capped_graph(centers, d_adj, max_degree)
    got = capped_semantic_graph(centers, d_adj, max_degree)
    assert_same_csr(got.adjacency, expected)
    assert_same_csr(semantic_graph(centers, d_adj, max_degree), expected)
    assert got.capped_nodes == expected_capped == capped
    assert got.tree.n == len(centers) and np.array_equal(got.tree.data, centers)  # index_map keeps it for localize


def test_capped_graph_is_the_knn_graph_and_ball_count_on_random_maps():
    """Random maps, integer grids (exact distances, duplicates) and pairs a few ulps either side of d_adj, with
    caps that bite and caps that do not: the very arrays and count the k-nearest and ball queries gave."""
    rng = np.random.default_rng(3)
    for trial in range(400):
        n, kind = int(rng.integers(0, 90)), trial % 4
        if kind == 0:
            centers = rng.uniform(0, 3, (n, 3))
        elif kind == 1:
            centers = rng.integers(0, 4, (n, 3)).astype(float)
        elif kind == 2:
            centers = rng.integers(0, 3, (n, 3)) * 0.4
        else:
            base, ways = rng.uniform(0, 3, (n, 3)), rng.normal(size=(n, 3))
            ways /= np.linalg.norm(ways, axis=1, keepdims=True)
            centers = np.concatenate((base, base + ways * 0.8 * (1 + rng.integers(-4, 5, (n, 1)) * 2.0**-52)))
        d_adj, max_degree = [1.0, 0.8, 0.4][trial % 3], int(rng.choice([1, 3, 8, 64]))
        expected, expected_capped = knn_capped_graph(centers, d_adj, max_degree)
        got = capped_semantic_graph(centers, d_adj, max_degree)
        assert_same_csr(got.adjacency, expected)
        assert got.capped_nodes == expected_capped


def test_query_histograms_store_the_sparse_paths_entries_bit_for_bit():
    """The compiled query path must give the very arrays (order included: a product sums in stored
    order) of the sparse path, with and without a soft class kernel, for every walk length."""
    rng = np.random.default_rng(0)
    for trial in range(120):
        n, classes, length = int(rng.integers(0, 25)), int(rng.integers(1, 9)), int(rng.integers(1, 5))
        centers, ids = rng.uniform(0, 2, (n, 3)), rng.integers(0, classes, n)
        kernel = None if trial % 2 else sp.csr_matrix(np.where(rng.random((classes, classes)) < 0.3,
                                                               rng.random((classes, classes)), 0) + np.eye(classes))
        expected = semantic_histograms(semantic_graph(centers, 0.8, 64), ids, classes, length, kernel)
        got = query_histograms(centers, ids, classes, 0.8, 64, length, kernel)
        assert got.shape == expected.shape
        for name in ("indptr", "indices"):
            np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
        assert got.data.dtype == np.float64
        np.testing.assert_allclose(got.data, expected.data, rtol=1e-12, atol=0)
    assert query_histograms(np.zeros((0, 3)), np.zeros(0, int), 3, 0.8, 64).shape == (0, 27)


def test_landmark_histograms_store_the_sparse_paths_entries():
    """The compiled map path gives the sparse path's entries (the same positions; values within rounding), with
    exact labels and with the map's own class distributions, on graphs with and without the degree cap biting,
    every walk length."""
    rng = np.random.default_rng(1)
    for trial in range(120):
        n, classes, length = int(rng.integers(0, 80)), int(rng.integers(1, 9)), int(rng.integers(1, 5))
        centers, ids = rng.uniform(0, 2, (n, 3)), rng.integers(0, classes, n)
        adjacency = semantic_graph(centers, 0.8, int(rng.choice([3, 64])))
        distributions = None if trial % 2 else sp.csr_matrix(
            np.where(rng.random((n, classes)) < 0.4, rng.random((n, classes)), 0.0))
        expected = semantic_histograms(adjacency, ids, classes, length, None, distributions)
        got = landmark_histograms(adjacency, ids, classes, length, distributions)
        assert got.shape == expected.shape
        for name in ("indptr", "indices"):
            np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
        np.testing.assert_allclose(got.data, expected.data, rtol=1e-12, atol=0)


def test_inverse_row_norms_are_numpys_formula():
    """`_inverse_norms` against what it replaced (np.add.reduceat of the squares of the non-empty rows, np.sqrt,
    np.where/np.maximum) within rounding, on rows of every length numpy's pairwise sum splits differently (1 to 4,099
    entries), empty rows, zeros and -0, NaN, infinities, and norms below 1e-300."""
    from clipclique.descriptors.graph import _inverse_norms

    def reference(pointers, values):
        norms = np.zeros(len(pointers) - 1)
        rows = np.flatnonzero(np.diff(pointers))
        with np.errstate(over="ignore", invalid="ignore"):
            norms[rows] = np.add.reduceat(values * values, pointers[rows])
            norms = np.sqrt(norms)
            return np.where(norms > 0, 1.0 / np.maximum(norms, 1e-300), 0.0)

    rng = np.random.default_rng(6)
    lengths = [0, 1, 2, 7, 8, 9, 15, 16, 17, 127, 128, 129, 130, 255, 256, 257, 300, 1000, 4099, 0]
    special = [np.zeros(5), np.array([-0.0, 0.0, -0.0]), np.array([1.0, np.nan, 2.0]), np.array([np.inf, 1.0]),
               np.full(3, 1e-160), np.full(20, 1e-170), np.array([1e200, 1e200])]
    rows = [rng.normal(size=length) * 10.0 ** rng.integers(-3, 4) for length in lengths] + special
    rows += [rng.random(int(length)) for length in rng.integers(0, 400, 60)]
    pointers = np.r_[0, np.cumsum([len(row) for row in rows])].astype(np.int64)
    values = np.concatenate(rows)
    expected = reference(pointers, values)
    got = _inverse_norms(pointers, values)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)
    assert _inverse_norms(np.zeros(1, np.int64), np.zeros(0)).shape == (0,)


@pytest.mark.parametrize("length", [1, 2, 3, 4])
def test_normalized_walks_are_the_two_pass_normalization(length):
    """The walks normalized row by row in their last step against what they replaced (the raw walks, then
    `_scale_rows(..., _inverse_norms(...))`), within rounding: isolated nodes, a lone node's empty row, -0,
    NaN, labels whose squares underflow (norm 0: all dropped) and entries the scaling rounds to 0 (dropped)."""
    from clipclique.descriptors.graph import _inverse_norms, _scale_rows, _walk_histograms

    adjacency = semantic_graph(np.array([[0, 0, 0], [0.5, 0, 0], [0.25, 0.4, 0], [0.25, 1.1, 0], [5, 5, 5],
                                         [9, 9, 9], [9.5, 9, 9], [20, 0, 0], [20.5, 0, 0.0]]), 0.8)
    distributions = sp.csr_matrix(np.array([
        [1.0, 0.0, 0.0], [0.0, 0.5, -0.0], [0.3, 0.3, 0.4], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0],
        [np.nan, 1.0, 0.0], [0.0, 1.0, 0.0], [1e-170, 1e-170, 0.0], [1e200, 0.0, 1e-200]]))
    distributions.data[1] = -0.0  # a stored -0 among the labels
    arrays = (adjacency.indptr.astype(np.int64), adjacency.indices.astype(np.int64),
              distributions.indptr.astype(np.int64), distributions.indices.astype(np.int64), distributions.data)
    raw = _walk_histograms(*arrays, 3, length)
    expected = _scale_rows(*raw, _inverse_norms(raw[0], raw[2]))
    got = _walk_histograms(*arrays, 3, length, True)
    for ours, theirs in zip(got, expected):
        assert ours.dtype == theirs.dtype
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=0)
    assert np.isnan(got[2]).any() and got[0][-1] < raw[0][-1]  # NaN kept, underflowed entries dropped
    empty = _walk_histograms(np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(1, np.int64),
                             np.zeros(0, np.int64), np.zeros(0), 3, length, True)
    assert [len(part) for part in empty] == [1, 0, 0]
