import numpy as np
import pytest

from hpcves.numerics.reductions import largest_magnitude, maximum, minimum


@pytest.mark.parametrize("n", [1, 7, 128])
def test_extremes_agree_with_numpy(n, rng):
    for _ in range(20):
        x = rng.standard_normal(n)
        z = x + 1j * rng.standard_normal(n)
        assert maximum(x) == x.max() and minimum(x) == x.min()
        assert largest_magnitude(x) == np.abs(x).max()
        assert largest_magnitude(z) == np.abs(z).max()


def test_a_nan_propagates_as_in_numpy():
    x = np.array([0.0, 3.0, np.nan, -5.0])
    assert np.isnan(maximum(x)) and np.isnan(minimum(x)) and np.isnan(largest_magnitude(x))
    assert not largest_magnitude(x) <= 1.0          # as tolerances are tested: a NaN fails them
