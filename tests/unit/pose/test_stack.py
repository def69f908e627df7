import numpy as np

from clipclique.pose.stack import Stack, alike
from clipclique.types import Hypothesis, Pose


def alike_by_bytes(poses, pairs, starts, counts):
    """Groups by each item's bytes (pose as float64, pairs as int64) in a dict, firsts by np.unique."""
    seen: dict[bytes, int] = {}
    group = np.array([seen.setdefault(poses[r].astype(np.float64).tobytes()
                                      + pairs[start: start + count].astype(np.int64).tobytes(), len(seen))
                      for r, (start, count) in enumerate(zip(starts, counts))], np.int64)
    return group, np.unique(group, return_index=True)[1]


def test_alike_items_are_those_with_the_same_bytes():
    """Repeated items, poses differing only in the sign of a zero or holding NaN, pairs that begin alike, empty sets,
    pairs (M, 2) and single numbers (M,)."""
    rng = np.random.default_rng(0)
    for trial in range(300):
        count, width = int(rng.integers(0, 12)), int(rng.choice([0, 3, 12]))
        poses = rng.choice([0.0, -0.0, 1.5, np.nan], size=(count, width))
        counts = rng.integers(0, 4, count)
        pairs = rng.integers(0, 2, (int(counts.sum()), 2))
        starts = np.cumsum(counts) - counts
        repeat = rng.integers(0, max(count, 1), count // 2)  # items copied onto others: alike
        for source, target in zip(repeat, rng.integers(0, max(count, 1), count // 2)):
            if counts[source] == counts[target]:
                poses[target] = poses[source]
                pairs[starts[target]: starts[target] + counts[target]] = (
                    pairs[starts[source]: starts[source] + counts[source]])
        for values in (pairs, pairs[:, 0]):  # pairs, and sets of single numbers
            group, firsts = alike(poses, values, starts, counts)
            expected_group, expected_firsts = alike_by_bytes(poses, values, starts, counts)
            assert group.dtype == firsts.dtype == np.int64
            np.testing.assert_array_equal(group, expected_group)
            np.testing.assert_array_equal(firsts, expected_firsts)


def test_a_stack_takes_rows_with_their_pairs_and_gives_back_its_hypotheses():
    rng = np.random.default_rng(1)
    hypotheses = [Hypothesis(Pose(rng.normal(size=(3, 3)), rng.normal(size=3)), rng.integers(0, 9, (size, 2)),
                             float(size), 0.5 * size) for size in [3, 0, 5, 4]]
    stack = Stack.of(hypotheses)
    taken = stack.take(np.array([3, 1, 0]))
    np.testing.assert_array_equal(taken.counts, [4, 0, 3])
    for got, source in zip(taken.hypotheses(verification=[0.25, 0.5, 0.75]), [3, 1, 0]):
        np.testing.assert_array_equal(got.correspondences, hypotheses[source].correspondences)
        np.testing.assert_array_equal(got.pose.rotation, hypotheses[source].pose.rotation)  # taken, not computed
        assert ((got.score, got.conditioning, got.confidence)
                == (hypotheses[source].score, hypotheses[source].conditioning, None))
    assert [h.verification for h in taken.hypotheses(verification=[0.25, 0.5, 0.75])] == [0.25, 0.5, 0.75]
    chosen = stack.hypotheses(np.array([2, 0, 2]), [0.1, 0.2, 0.3], [0.6, 0.7, 0.8])  # one value per row chosen
    assert [(h.score, h.verification, h.confidence) for h in chosen] == [(5.0, 0.1, 0.6), (3.0, 0.2, 0.7),
                                                                          (5.0, 0.3, 0.8)]
    np.testing.assert_array_equal(chosen[0].correspondences, hypotheses[2].correspondences)
    assert type(chosen[0].score) is float and type(chosen[0].conditioning) is float
    joined = Stack.joined([taken, stack])
    np.testing.assert_array_equal(joined.pairs, np.concatenate((taken.pairs, stack.pairs)))
    assert len(Stack.joined([])) == 0 and len(Stack.of([])) == 0
