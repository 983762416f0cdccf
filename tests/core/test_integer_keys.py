import numpy as np
import pytest

from sssbake.pipeline.core.integer_keys import argsort_keys, unique_keys


@pytest.mark.parametrize("bound", [1, 2, 1000, 65536, 65537, 10**7, 2**40 + 3])
def test_argsort_keys_is_numpys_stable_order(bound):
    # one, two and three 16-bit digits, with many ties so that stability shows
    rng = np.random.default_rng(bound)
    key = rng.integers(0, bound, 20_000)
    key[::7] = key[0]
    assert np.array_equal(argsort_keys(key, bound), np.argsort(key, kind="stable"))


def test_argsort_keys_of_nothing_and_of_sorted_keys():
    assert argsort_keys(np.zeros(0, dtype=np.int64), 10).shape == (0,)
    assert np.array_equal(argsort_keys(np.arange(70_000), 70_000), np.arange(70_000))


@pytest.mark.parametrize("bound", [1, 50, 70_000, 3 * 2**33])
def test_unique_keys_is_numpys_unique(bound):
    key = np.random.default_rng(bound).integers(0, bound, 20_000)
    first, inverse = unique_keys(key, bound)
    _, np_first, np_inverse = np.unique(key, return_index=True, return_inverse=True)
    assert np.array_equal(first, np_first) and np.array_equal(inverse, np_inverse.reshape(-1))
    assert unique_keys(np.zeros(0, dtype=np.int64), 10)[0].shape == (0,)
