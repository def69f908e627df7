"""numpybits' np.maximum rule and the maximum of an array, held to numpy's own."""

import numpy as np
import pytest
from numba import njit

from clipclique.numpybits import largest, maximum

SPECIAL = [np.nan, np.inf, -np.inf, 0.0, 1.5, -2.0, 1e-300]


@njit(cache=True)
def _maximum(a, b):  # the inlined helper as its callers compile it
    return maximum(a, b)


@njit(cache=True)
def _largest(values):
    return largest(values)


@pytest.mark.parametrize("a", SPECIAL)
@pytest.mark.parametrize("b", SPECIAL)
def test_maximum_is_np_maximum(a, b):
    got, expected = _maximum(a, b), np.maximum(a, b)
    assert np.isnan(got) == np.isnan(expected)
    if not np.isnan(expected):
        assert got == expected


def test_maximum_keeps_its_first_operand_on_a_tie():
    assert np.signbit(_maximum(-0.0, 0.0)) and not np.signbit(_maximum(0.0, -0.0))


def test_largest_is_the_arrays_max_nan_included():
    rng = np.random.default_rng(3)
    for size in (1, 2, 7, 33):
        for _ in range(50):
            values = rng.normal(size=size)
            for place in rng.choice(size, size=rng.integers(0, 3), replace=True):
                values[place] = rng.choice([np.nan, np.inf, -np.inf])
            got, expected = _largest(values), values.max()
            assert np.isnan(got) == np.isnan(expected), values
            if not np.isnan(expected):
                assert got == expected, values
    assert np.isnan(_largest(np.array([3.0, np.nan, 9.0])))  # NaN wins, wherever it stands
    assert _largest(np.array([-1.0, -0.5, -4.0])) == -0.5
