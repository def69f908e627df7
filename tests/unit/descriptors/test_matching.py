import numpy as np
import pytest
import scipy.sparse as sp

from clipclique.config import MatchingConfig
from clipclique.descriptors.matching import (
    FLAT,
    SELECTED_UP_TO,
    Lookalikes,
    adaptive_matches,
    best_rows,
    cap,
    class_groups,
    knn_matches,
    match,
    mutual_best_matches,
    top_m,
    with_lookalikes,
)


def test_adaptive_keeps_the_landmarks_above_the_largest_gap():
    # sorted row: 0.9 (lm 3), 0.85 (lm 0), 0.3 (lm 4), 0.2 (lm 1), 0.1 (lm 2): largest gap after 2 values
    row = np.array([[0.85, 0.2, 0.1, 0.9, 0.3, 0.05]])
    np.testing.assert_array_equal(adaptive_matches(row, 5), [[0, 3], [0, 0]])


def test_adaptive_only_looks_at_the_top_m():
    # within the top 3 (0.9, 0.8, 0.6) the largest gap is after 0.8; the bigger gap 0.6 -> 0.0 is outside
    row = np.array([[0.9, 0.8, 0.6, 0.0]])
    np.testing.assert_array_equal(adaptive_matches(row, 3), [[0, 0], [0, 1]])
    np.testing.assert_array_equal(adaptive_matches(row, 4), [[0, 0], [0, 1], [0, 2]])


def test_adaptive_ties_flat_rows_and_small_m():
    tied = np.array([[1.0, 0.75, 0.5, 0.25]])  # equal gaps: the first wins, one candidate
    np.testing.assert_array_equal(adaptive_matches(tied, 4), [[0, 0]])
    flat = np.array([[0.5, 0.5, 0.5, 0.5]])  # no gap: all top m kept
    np.testing.assert_array_equal(adaptive_matches(flat, 3), [[0, 0], [0, 1], [0, 2]])
    single = np.array([[0.4], [0.7]])  # one landmark: m = 1, the best is kept
    np.testing.assert_array_equal(adaptive_matches(single, top_m(1, 0.25)), [[0, 0], [1, 0]])


def test_adaptive_rows_are_independent():
    rows = np.array([[0.9, 0.1, 0.8, 0.0], [0.2, 0.9, 0.1, 0.15]])
    np.testing.assert_array_equal(adaptive_matches(rows, 4), [[0, 0], [0, 2], [1, 1]])


def test_adaptive_on_long_rows_keeps_what_a_full_stable_sort_keeps():
    """Long rows take a shortcut (sorted values first, then only the kept landmarks): the same pairs in the
    same order as the gap rule on a full stable sort, with plateaus of copies (a map of identical rooms),
    ties at the gap, flat rows and negative values."""
    rng = np.random.default_rng(1)
    for trial in range(60):
        width = int(rng.integers(1024, 4000))
        rooms = int(rng.choice([1, 10, 100]))
        one = np.round(rng.random((int(rng.integers(1, 10)), max(1, width // rooms))), int(rng.choice([1, 2, 6])))
        similarity = np.tile(one, (1, rooms))[:, :width] - (0.5 if trial % 4 == 0 else 0.0)
        if trial % 7 == 0:
            similarity[0] = 0.25  # flat: every one of the top m kept
        m = int(rng.integers(2, width // 2 + 1))
        order = np.argsort(-similarity, axis=1, kind="stable")[:, :m]
        values = np.take_along_axis(similarity, order, axis=1)
        gaps = values[:, :-1] - values[:, 1:]
        count = np.where(gaps.max(axis=1) > 1e-12, gaps.argmax(axis=1) + 1, m)
        keep = np.arange(m)[None] < count[:, None]
        expected = np.column_stack((np.repeat(np.arange(len(order)), m).reshape(order.shape)[keep], order[keep]))
        np.testing.assert_array_equal(adaptive_matches(similarity, m), expected)


@pytest.mark.parametrize(("landmarks", "expected"), [(40, 10), (41, 11), (3, 2), (1, 1), (0, 0)])
def test_top_m_is_a_quarter_at_least_two(landmarks, expected):
    assert top_m(landmarks, 0.25) == expected


def test_knn_takes_the_k_best_per_row():
    similarity = np.array([[0.1, 0.5, 0.3, 0.9], [0.4, 0.4, 0.0, 0.2]])
    np.testing.assert_array_equal(knn_matches(similarity, 3), [[0, 3], [0, 1], [0, 2], [1, 0], [1, 1], [1, 3]])
    assert len(knn_matches(similarity[:, :2], 3)) == 4


def test_mutual_best_keeps_only_pairs_that_choose_each_other():
    similarity = np.array([[0.9, 0.1, 0.0], [0.8, 0.2, 0.1], [0.0, 0.3, 0.7]])
    # obs 1's best is lm 0, but lm 0 prefers obs 0
    np.testing.assert_array_equal(mutual_best_matches(similarity), [[0, 0], [2, 2]])


def test_match_drops_candidates_at_or_below_min_similarity():
    similarity = np.array([[0.9, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    candidates, scores, _ = match(similarity, MatchingConfig(strategy="knn", k=2, min_similarity=0.0))
    np.testing.assert_array_equal(candidates, [[0, 0]])
    np.testing.assert_array_equal(scores, [0.9])


def test_empty_inputs_give_no_candidates():
    for strategy in ("adaptive", "knn", "one_to_one"):
        candidates, scores, _ = match(np.zeros((0, 5)), MatchingConfig(strategy=strategy))
        assert candidates.shape == (0, 2) and scores.shape == (0,)


def test_cap_keeps_the_best_scored_candidates_in_row_order():
    candidates = np.column_stack((np.repeat(np.arange(4), 3), np.tile(np.arange(3), 4)))
    scores = np.array([0.9, 0.5, 0.1, 0.8, 0.8, 0.2, 0.3, 0.95, 0.0, 0.8, 0.6, 0.4])
    kept, kept_scores, hit = cap(candidates, scores, limit=5)
    assert hit
    np.testing.assert_array_equal(kept_scores, [0.9, 0.8, 0.8, 0.95, 0.8])  # ties at 0.8 by row: rows 3, 4, 9
    np.testing.assert_array_equal(kept, candidates[[0, 3, 4, 7, 9]])
    np.testing.assert_array_equal(best_rows(scores, 5), [0, 3, 4, 7, 9])  # the rows, for marks that ride along
    same, _, hit = cap(candidates, scores, limit=12)
    assert not hit and same is candidates and best_rows(scores, 12) is None


def test_long_rows_pick_the_same_best_landmarks_as_a_full_stable_sort():
    """From PARTIAL_SORT_FROM landmarks a row's best are picked by partition: the same pairs, in the same
    order, as the full stable sort, ties included."""
    rng = np.random.default_rng(0)
    for trial in range(40):
        similarity = np.round(rng.random((int(rng.integers(1, 12)), int(rng.integers(1024, 3000)))), 2)  # ties
        similarity[:, ::5] = similarity[:, :1]
        k = int(rng.integers(1, similarity.shape[1] // 2))
        order = np.argsort(-similarity, axis=1, kind="stable")[:, :k]
        expected = np.column_stack((np.repeat(np.arange(len(order)), k), order.ravel()))
        np.testing.assert_array_equal(knn_matches(similarity, k), expected)


def test_adaptive_matches_are_the_largest_gap_rule_of_the_sorted_rows():
    """The compiled pass against the rule written with numpy: ties, flat rows and NaN included."""
    rng = np.random.default_rng(0)
    for trial in range(300):
        similarity = np.round(rng.random((int(rng.integers(1, 16)), int(rng.integers(1, 120)))), 1 + trial % 3)
        if trial % 7 == 0:
            similarity[rng.random(similarity.shape) < 0.05] = np.nan
        if trial % 11 == 0:
            similarity[:] = 0.5
        m = top_m(similarity.shape[1], (0.05, 0.25, 1.0)[trial % 3])
        order = np.argsort(-similarity, axis=1, kind="stable")[:, :m]
        gaps = -np.diff(np.take_along_axis(similarity, order, axis=1), axis=1)
        count = (np.where(gaps.max(axis=1, initial=-np.inf) > FLAT, gaps.argmax(axis=1) + 1, m) if m > 1
                 else np.ones(len(order), int))
        expected = [(i, order[i, j]) for i in range(len(order)) for j in range(count[i])]
        np.testing.assert_array_equal(adaptive_matches(similarity, m), np.array(expected).reshape(-1, 2))


def test_adaptive_selection_of_few_is_the_stable_argsorts_order_on_special_values():
    """Up to SELECTED_UP_TO best per row are picked by a compiled insertion: the same pairs in the same order as the
    gap rule (and kNN) on numpy's stable argsort, with 0 and -0 tied, infinities, NaN (last) and every m from 1 to the
    row."""
    rng = np.random.default_rng(5)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, 0.5, 0.25, -1.0])
    for trial in range(200):
        shape = (int(rng.integers(1, 9)), int(rng.integers(1, 90)))
        similarity = rng.choice(special, shape) if trial % 2 else np.round(rng.random(shape), 1)
        most = min(shape[1], SELECTED_UP_TO)
        for m in {1, min(2, most), most, int(rng.integers(1, most + 1))}:
            order = np.argsort(-similarity, axis=1, kind="stable")[:, :m]
            with np.errstate(invalid="ignore"):
                gaps = -np.diff(np.take_along_axis(similarity, order, axis=1), axis=1)
            undefined = np.isnan(gaps).any(axis=1)
            count = (np.where((gaps.max(axis=1, initial=-np.inf) > FLAT) & ~undefined, gaps.argmax(axis=1) + 1, m)
                     if m > 1 else np.ones(len(order), int))
            expected = [(i, order[i, j]) for i in range(len(order)) for j in range(count[i])]
            got = adaptive_matches(similarity, m)
            np.testing.assert_array_equal(got, np.array(expected).reshape(-1, 2))
            assert got.dtype == np.int64
            nearest = knn_matches(similarity, m)
            np.testing.assert_array_equal(nearest,
                                          np.column_stack((np.repeat(np.arange(len(order)), m), order.ravel())))
            assert nearest.dtype == np.int64


def test_the_similarity_floor_is_numpys_gather_and_selection():
    """`match`'s floor (one compiled pass) against the numpy gather, comparison and selections: NaN, -0 and
    floors at a value, every strategy, and no candidates at all."""
    rng = np.random.default_rng(6)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 0.5, 0.25, -0.5])
    for trial in range(100):
        similarity = rng.choice(special, (int(rng.integers(0, 6)), int(rng.integers(1, 12))))
        for strategy, floor in (("adaptive", 0.0), ("knn", 0.25), ("one_to_one", -1.0), ("knn", -0.0)):
            config = MatchingConfig(strategy=strategy, min_similarity=floor, k=3, top_m_fraction=0.5)
            with np.errstate(invalid="ignore"):
                candidates = {"adaptive": adaptive_matches(similarity, top_m(similarity.shape[1], 0.5)),
                              "knn": knn_matches(similarity, 3),
                              "one_to_one": mutual_best_matches(similarity)}[strategy]
            scores = similarity[candidates[:, 0], candidates[:, 1]]
            with np.errstate(invalid="ignore"):
                keep = scores > floor
            got = match(similarity, config)
            np.testing.assert_array_equal(got[0], candidates[keep])
            assert got[0].dtype == np.int64 and got[0].shape == (keep.sum(), 2)
            np.testing.assert_array_equal(got[1], scores[keep])  # gathered, not computed
            np.testing.assert_array_equal(got[2], np.zeros(keep.sum(), bool))
            assert got[2].dtype == np.bool_


def _reference_with_lookalikes(candidates, similarity, kernel, landmark_classes, observed_classes, observed_axes,
                               landmark_axes, per_class, ratio):
    """The (K, N) mask and numpy sorts `with_lookalikes` replaced (commit 290fca9), the literal reference."""
    lookalike = ((kernel.toarray()[:, landmark_classes][observed_classes] > 0)
                 & (observed_classes[:, None] != landmark_classes[None]))
    rows, columns = np.nonzero(lookalike)
    observed, mapped = np.sort(observed_axes, axis=1)[rows], np.sort(landmark_axes, axis=1)[columns]
    apart = (np.maximum(observed, mapped) > ratio * np.minimum(observed, mapped)).any(axis=1)
    lookalike[rows[apart], columns[apart]] = False
    rows, columns = np.nonzero(lookalike)
    if per_class == 0 or len(rows) == 0:
        return candidates, np.zeros(len(candidates), bool)
    values = similarity[rows, columns]
    order = np.lexsort((columns, -values, landmark_classes[columns], rows))
    rows, columns, classes = rows[order], columns[order], landmark_classes[columns[order]]
    group = np.r_[True, (rows[1:] != rows[:-1]) | (classes[1:] != classes[:-1])]
    starts = np.flatnonzero(group)
    rank = np.arange(len(rows)) - np.repeat(starts, np.diff(np.r_[starts, len(rows)]))
    added = np.column_stack((rows[rank < per_class], columns[rank < per_class])).astype(np.int64)
    merged = np.unique(np.concatenate((candidates, added)), axis=0)
    scores = similarity[merged[:, 0], merged[:, 1]]
    merged = merged[np.lexsort((merged[:, 1], -scores, merged[:, 0]))]
    kept = np.zeros(similarity.shape, bool)
    kept[candidates[:, 0], candidates[:, 1]] = True
    return merged, ~kept[merged[:, 0], merged[:, 1]]


def _kernel(num_classes, pairs):
    """(C, C) a class kernel: 1 on the diagonal, 0.6 between the look-alike `pairs`."""
    rows = [a for a, b in pairs] + [b for a, b in pairs] + list(range(num_classes))
    columns = [b for a, b in pairs] + [a for a, b in pairs] + list(range(num_classes))
    return sp.csr_matrix((np.r_[np.full(2 * len(pairs), 0.6), np.ones(num_classes)], (rows, columns)),
                         shape=(num_classes, num_classes))


def _both(candidates, similarity, kernel, landmark_classes, observed_classes, per_class, observed_axes=None,
          landmark_axes=None, ratio=1.5):
    """`with_lookalikes` and the reference on one case, checked equal; the compiled result."""
    observed_axes = np.ones((len(similarity), 3)) if observed_axes is None else observed_axes
    landmark_axes = np.ones((similarity.shape[1], 3)) if landmark_axes is None else landmark_axes
    lookalikes = Lookalikes(groups=class_groups(landmark_classes, kernel, landmark_axes), classes=observed_classes,
                            axes=observed_axes)  # as observed: the compiled pass sorts each row
    merged, added = with_lookalikes(candidates, similarity, lookalikes, per_class, ratio)
    expected, expected_added = _reference_with_lookalikes(candidates, similarity, kernel, landmark_classes,
                                                          observed_classes, observed_axes, landmark_axes, per_class,
                                                          ratio)
    np.testing.assert_array_equal(merged, expected)
    np.testing.assert_array_equal(added, expected_added)
    assert merged.dtype == expected.dtype and added.dtype == expected_added.dtype
    return merged, added


def test_with_lookalikes_adds_each_observations_best_of_every_lookalike_class():
    similarity = np.array([[0.9, 0.3, 0.35, 0.2, 0.1],
                           [0.1, 0.8, 0.2, 0.2, 0.6]])
    landmark_classes = np.array([0, 1, 1, 2, 2])
    kernel = _kernel(4, [(0, 1), (0, 2)])  # observation 0 (class 0): classes 1 and 2 look alike; 1 (class 3): none
    observed_classes = np.array([0, 3])
    candidates = np.array([[0, 0], [1, 1]])
    # best of class 1 for observation 0 is landmark 2 (0.35), of class 2 landmark 3 (0.2); kept best first
    merged, added = _both(candidates, similarity, kernel, landmark_classes, observed_classes, 1)
    np.testing.assert_array_equal(merged, [[0, 0], [0, 2], [0, 3], [1, 1]])
    np.testing.assert_array_equal(added, [False, True, True, False])
    merged, added = _both(candidates, similarity, kernel, landmark_classes, observed_classes, 2)
    np.testing.assert_array_equal(merged, [[0, 0], [0, 2], [0, 1], [0, 3], [0, 4], [1, 1]])
    np.testing.assert_array_equal(added, [False, True, True, True, True, False])
    merged, added = _both(candidates, similarity, kernel, landmark_classes, observed_classes, 0)
    np.testing.assert_array_equal(merged, candidates)
    assert not added.any()
    already = np.array([[0, 0], [0, 2], [1, 1]])  # a pair the gap rule kept is not added twice, nor marked
    merged, added = _both(already, similarity, kernel, landmark_classes, observed_classes, 1)
    np.testing.assert_array_equal(merged, [[0, 0], [0, 2], [0, 3], [1, 1]])
    np.testing.assert_array_equal(added, [False, False, True, False])


def test_with_lookalikes_breaks_equal_similarities_by_landmark_index():
    similarity = np.array([[0.9, 0.4, 0.4, 0.4, 0.4, 0.4]])
    landmark_classes = np.array([0, 2, 1, 2, 1, 1])  # classes interleaved: grouping must keep index order
    kernel = _kernel(3, [(0, 1), (0, 2)])
    merged, added = _both(np.array([[0, 0]]), similarity, kernel, landmark_classes, np.array([0]), 2)
    np.testing.assert_array_equal(merged, [[0, 0], [0, 1], [0, 2], [0, 3], [0, 4]])  # landmark 5 ranks third of 1
    np.testing.assert_array_equal(added, [False, True, True, True, True])


def test_with_lookalikes_leaves_the_candidates_as_they_came_without_lookalikes():
    similarity = np.array([[0.2, 0.9, 0.5], [0.3, 0.1, 0.8]])
    candidates = np.array([[1, 2], [0, 1], [0, 2]])  # not in row order: nothing is merged, so nothing is sorted
    merged, added = _both(candidates, similarity, _kernel(2, []), np.array([0, 1, 1]), np.array([0, 1]), 2)
    np.testing.assert_array_equal(merged, candidates)
    assert not added.any()
    # look-alike classes, but none of a size with the observation: the same
    kernel = _kernel(2, [(0, 1)])
    landmark_axes = np.full((3, 3), 2.0)
    merged, _ = _both(candidates, similarity, kernel, np.array([0, 1, 1]), np.array([0, 0]), 2,
                      landmark_axes=landmark_axes)
    np.testing.assert_array_equal(merged, candidates)


def test_with_lookalikes_keeps_a_whole_class_smaller_than_per_class_and_only_landmarks_of_a_size():
    similarity = np.array([[0.9, 0.1, 0.7, 0.3, 0.5]])
    landmark_classes = np.array([0, 1, 1, 1, 1])
    landmark_axes = np.array([[1.0, 1, 1], [1, 1, 1], [1, 1, 1.6], [1, 1.4, 1], [1, 1, 1]])  # landmark 2 is apart
    merged, added = _both(np.array([[0, 0]]), similarity, _kernel(2, [(0, 1)]), landmark_classes, np.array([0]), 10,
                          landmark_axes=landmark_axes)
    np.testing.assert_array_equal(merged, [[0, 0], [0, 4], [0, 3], [0, 1]])
    np.testing.assert_array_equal(added, [False, True, True, True])


def test_with_lookalikes_matches_the_numpy_reference_on_random_maps_with_ties_and_nan():
    generator = np.random.default_rng(7)
    for trial in range(300):
        num_obs, num_landmarks, num_classes = (generator.integers(1, 8), generator.integers(1, 40),
                                               generator.integers(1, 6))
        similarity = generator.integers(0, 5, (num_obs, num_landmarks)) / 4.0  # few values: many ties
        if trial % 5 == 0:
            similarity[generator.random(similarity.shape) < 0.1] = np.nan
        landmark_classes = generator.integers(0, num_classes, num_landmarks)
        pairs = [(a, b) for a in range(num_classes) for b in range(a + 1, num_classes) if generator.random() < 0.5]
        candidates = adaptive_matches(similarity, top_m(num_landmarks, 0.25))
        _both(candidates, similarity, _kernel(num_classes, pairs), landmark_classes,
              generator.integers(0, num_classes, num_obs), int(generator.integers(1, 5)),
              observed_axes=generator.uniform(0.5, 1.5, (num_obs, 3)),
              landmark_axes=generator.uniform(0.5, 1.5, (num_landmarks, 3)), ratio=float(generator.uniform(1.0, 2.0)))


def test_match_adds_lookalikes_only_when_asked_and_only_to_adaptive_matching():
    similarity = np.array([[0.9, 0.3, 0.35, 0.2]])
    classes = np.array([0, 1, 1, 2])
    lookalikes = Lookalikes(groups=class_groups(classes, _kernel(3, [(0, 1)]), np.ones((4, 3))),
                            classes=np.array([0]), axes=np.ones((1, 3)))
    on = MatchingConfig(strategy="adaptive", top_m_fraction=1.0, lookalike_candidates=1)
    candidates, scores, added = match(similarity, on, lookalikes)
    np.testing.assert_array_equal(candidates, [[0, 0], [0, 2]])
    np.testing.assert_array_equal(scores, [0.9, 0.35])
    np.testing.assert_array_equal(added, [False, True])
    off = MatchingConfig(top_m_fraction=1.0, lookalike_candidates=0)
    np.testing.assert_array_equal(match(similarity, off, lookalikes)[0], [[0, 0]])
    # the floor holds for them too
    above = MatchingConfig(top_m_fraction=1.0, lookalike_candidates=1, min_similarity=0.4)
    np.testing.assert_array_equal(match(similarity, above, lookalikes)[0], [[0, 0]])
    knn = MatchingConfig(strategy="knn", k=1, lookalike_candidates=1)
    np.testing.assert_array_equal(match(similarity, knn, lookalikes)[0], [[0, 0]])


def test_adaptive_matching_with_lookalikes_in_one_call_is_the_three_steps():
    """`match`'s compiled path for short rows and few best (the gap rule, the look-alikes, the floor) against
    `adaptive_matches`, `with_lookalikes` and numpy's floor one after another: ties, NaN, floors, classes without
    look-alikes (candidates as they came) and every m the path takes."""
    generator = np.random.default_rng(8)
    for trial in range(300):
        num_obs, num_landmarks, num_classes = (generator.integers(1, 8), generator.integers(1, 60),
                                               generator.integers(1, 6))
        similarity = generator.integers(-1, 5, (num_obs, num_landmarks)) / 4.0
        if trial % 5 == 0:
            similarity[generator.random(similarity.shape) < 0.1] = np.nan
        landmark_classes = generator.integers(0, num_classes, num_landmarks)
        pairs = [(a, b) for a in range(num_classes) for b in range(a + 1, num_classes) if generator.random() < 0.5]
        axes = generator.uniform(0.5, 1.5, (num_landmarks, 3))
        lookalikes = Lookalikes(groups=class_groups(landmark_classes, _kernel(num_classes, pairs), axes),
                                classes=generator.integers(0, num_classes, num_obs),
                                axes=generator.uniform(0.5, 1.5, (num_obs, 3)))
        config = MatchingConfig(top_m_fraction=float(generator.choice([0.05, 0.25, 1.0])),
                                lookalike_candidates=int(generator.integers(1, 4)),
                                lookalike_size_ratio=float(generator.uniform(1.0, 2.0)),
                                min_similarity=float(generator.choice([0.0, -1.0, 0.25])))
        candidates, added = with_lookalikes(adaptive_matches(similarity, top_m(num_landmarks, config.top_m_fraction)),
                                            similarity, lookalikes, config.lookalike_candidates,
                                            config.lookalike_size_ratio)
        scores = similarity[candidates[:, 0], candidates[:, 1]]
        with np.errstate(invalid="ignore"):
            keep = scores > config.min_similarity
        got = match(similarity, config, lookalikes)
        np.testing.assert_array_equal(got[0], candidates[keep])
        np.testing.assert_array_equal(got[1], scores[keep])  # gathered, not computed
        np.testing.assert_array_equal(got[2], added[keep])
        assert got[0].dtype == np.int64 and got[2].dtype == np.bool_


def test_class_groups_group_landmarks_by_class_and_leave_a_class_out_of_its_own_lookalikes():
    groups = class_groups(np.array([2, 0, 2, 1]), _kernel(3, [(0, 2)]), np.array([[3.0, 1, 2]] * 4))
    np.testing.assert_array_equal(groups.landmarks, [1, 3, 0, 2])
    np.testing.assert_array_equal(groups.starts, [0, 1, 2, 4])
    np.testing.assert_array_equal(groups.lookalike_starts, [0, 1, 1, 2])
    np.testing.assert_array_equal(groups.lookalikes, [2, 0])
    np.testing.assert_array_equal(groups.axes, [[1.0, 2, 3]] * 4)
