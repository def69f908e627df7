import numpy as np
import scipy.sparse as sp

from clipclique.descriptors.graph import SparseRows, semantic_graph, semantic_histograms
from clipclique.descriptors.similarity import (
    COMPILED_ROWS_UP_TO,
    by_bin,
    clip_similarity,
    fuse,
    histogram_similarity,
    walk_similarity,
)


def test_histogram_similarity_is_cosine_of_histograms():
    rng = np.random.default_rng(0)
    centers = rng.uniform(0, 3, size=(30, 3))
    classes = rng.integers(0, 5, 30)
    histograms = semantic_histograms(semantic_graph(centers, 0.8), classes, 5)
    similarity = histogram_similarity(histograms[:4], by_bin(histograms))
    dense = histograms.toarray()
    np.testing.assert_allclose(similarity, dense[:4] @ dense.T)
    connected = np.flatnonzero(np.linalg.norm(dense, axis=1) > 0)[:4]
    np.testing.assert_allclose(histogram_similarity(histograms[connected], by_bin(histograms[connected])).diagonal(),
                               1.0)
    # a node's own class is each walk's first label: different classes never share a bin
    assert (similarity[classes[:4, None] != classes[None, :]] == 0).all()


def test_walk_similarity_is_the_fraction_of_shared_walks():
    query = sp.csr_matrix(np.array([[3.0, 1.0, 0.0, 0.0], [0.0, 0.0, 2.0, 2.0]]))
    landmarks = sp.csr_matrix(np.array([[5.0, 0.0, 0.0, 0.0], [0.0, 9.0, 1.0, 0.0]]))
    np.testing.assert_allclose(walk_similarity(query, landmarks), [[0.75, 0.25], [0.0, 0.5]])


def test_clip_and_fused_similarity():
    image = np.array([[1.0, 0.0], [0.6, 0.8]])
    text = np.array([[0.0, 1.0], [1.0, 0.0]])
    clip = clip_similarity(image, text)
    np.testing.assert_allclose(clip, [[0.0, 1.0], [0.8, 0.6]])
    np.testing.assert_allclose(fuse(clip, np.ones((2, 2)), 0.7), [[0.3, 1.0], [0.86, 0.72]])


def test_clip_similarity_of_a_small_frame_is_the_float64_product():
    """The compiled dot products (up to COMPILED_ROWS_UP_TO observations, any count of rows past a block of 4) against
    the exact sums of float32 embeddings' products: within 2e-16 (a few 1e-17 in fact), where one dropped term of 512
    moves a sum by some 1e-3; a larger frame keeps BLAS's product, bit for bit."""
    rng = np.random.default_rng(3)
    text = rng.normal(size=(37, 512)).astype(np.float32)
    text /= np.linalg.norm(text, axis=1, keepdims=True)
    for rows in (1, 3, 4, 7, COMPILED_ROWS_UP_TO, COMPILED_ROWS_UP_TO + 1):
        image = rng.normal(size=(rows, 512)).astype(np.float32)
        image /= np.linalg.norm(image, axis=1, keepdims=True)
        got = clip_similarity(image, text.astype(np.float64))
        exact = np.array([[float(np.dot(a.astype(np.longdouble), b.astype(np.longdouble))) for b in text]
                          for a in image])
        assert got.shape == (rows, 37) and got.dtype == np.float64
        assert np.abs(got - exact).max() < 2e-16
        if rows > COMPILED_ROWS_UP_TO:
            assert np.array_equal(got, image.astype(np.float64) @ text.astype(np.float64).T)


def test_histogram_similarity_is_scipys_sparse_product():
    rng = np.random.default_rng(1)
    centers = rng.uniform(0, 4, size=(200, 3))
    classes = rng.integers(0, 6, 200)
    kernel = sp.csr_matrix(np.eye(6) + 0.6 * (rng.random((6, 6)) < 0.2))
    histograms = semantic_histograms(semantic_graph(centers, 0.8), classes, 6, kernel=kernel)
    query = histograms[rng.permutation(200)[:20]]
    expected = (query @ histograms.T).toarray()
    np.testing.assert_allclose(histogram_similarity(query, by_bin(histograms)), expected, rtol=1e-12, atol=1e-15)
    # a frame's rows without a scipy matrix around them (graph.query_histograms), int64 columns: the same values
    rows = SparseRows(query.indptr.astype(np.int64), query.indices.astype(np.int64), query.data, query.shape)
    np.testing.assert_allclose(histogram_similarity(rows, by_bin(histograms)), expected, rtol=1e-12, atol=1e-15)


def test_the_class_term_is_the_numpy_formula_written_over_the_histogram():
    """`with_class_term` against `weight * classes[rows] + (1 - weight) * histogram` on hand-made values (0, -0, NaN,
    infinities, 1), weights 0, 1 and between, rows repeated or out of order, a (K, N) term with rows 0..K-1, and
    no observations or no landmarks."""
    from clipclique.descriptors.similarity import with_class_term

    rng = np.random.default_rng(12)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, 0.5, 1e-300])
    for weight in (0.0, 1.0, 0.3, 0.7, 1 / 3):
        for observations, landmarks in ((6, 9), (0, 9), (4, 0), (30, 200)):
            classes = rng.choice(special, (5, landmarks)) if landmarks < 100 else rng.random((5, landmarks))
            histogram = (rng.choice(special, (observations, landmarks)) if landmarks < 100
                         else rng.random((observations, landmarks)))
            rows = rng.integers(0, 5, observations)
            with np.errstate(invalid="ignore"):
                expected = weight * classes[rows] + (1.0 - weight) * histogram
            got = with_class_term(histogram, classes, rows, weight)
            assert got is histogram
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-300)
            term, histogram = rng.random((observations, landmarks)), rng.random((observations, landmarks))
            expected = weight * term + (1.0 - weight) * histogram
            got = with_class_term(histogram, term, np.arange(observations), weight)
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-300)


def test_fuse_is_the_numpy_formula_written_over_clip():
    """The compiled `fuse` against `alpha * clip + (1 - alpha) * histogram` on hand-made values (0, -0, NaN,
    infinities) and random ones, alphas 0, 1 and between, and no observations or no landmarks: the same values
    within rounding, NaN where numpy's is."""
    rng = np.random.default_rng(3)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, 0.5, 1e-300, -1.0])
    for alpha in (0.0, 1.0, 0.7, 1 / 3):
        for shape in ((6, 9), (0, 9), (4, 0), (30, 200)):
            pick = (lambda: rng.choice(special, shape)) if shape[1] < 100 else (lambda: rng.random(shape))
            clip, histogram = pick(), pick()
            with np.errstate(invalid="ignore"):
                expected = alpha * clip + (1.0 - alpha) * histogram
            got = fuse(clip, histogram, alpha)
            assert got is clip
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-300)
