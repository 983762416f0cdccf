"""Lloyd-Max quantiser: optimality conditions, closed-form SNR, degenerate inputs."""

import numpy as np
import pytest

from sssbake.pipeline.lloyd import lloyd_quantizer, snr_db


def test_uniform_data_reaches_the_closed_form_snr():
    x = np.random.default_rng(0).random(400_000)
    lut, codes = lloyd_quantizer(x)
    # uniform on [0, 1], 256 cells: noise Δ²/12 with Δ = 1/256, signal E[x²] = 1/3
    expected = 10 * np.log10((1 / 3) / ((1 / 256) ** 2 / 12))
    assert abs(snr_db(x, lut[codes]) - expected) < 0.1
    assert codes.dtype == np.uint8


def test_fixed_point_conditions_hold():
    x = np.random.default_rng(1).exponential(size=200_000)
    lut, codes = lloyd_quantizer(x, levels=16, iterations=500, tol=0.0)
    assert np.all(np.diff(lut) > 0)
    # nearest neighbour: each value's code is its nearest level
    nearest = np.abs(x[:, None] - lut[None, :]).argmin(axis=1)
    assert np.mean(codes == nearest) > 0.9999
    # centroid: each level is the mean of its cell
    means = np.bincount(codes, weights=x, minlength=16) / np.bincount(codes, minlength=16)
    np.testing.assert_allclose(lut, means, rtol=1e-3)
    # better than a uniform quantiser over the range on long-tailed data
    uniform = np.linspace(x.min(), x.max(), 16)
    assert snr_db(x, lut[codes]) > snr_db(x, uniform[np.abs(x[:, None] - uniform).argmin(axis=1)]) + 3.0


def test_few_distinct_values_are_exact():
    x = np.array([[3.0, 1.0], [1.0, 2.0]])
    lut, codes = lloyd_quantizer(x)
    np.testing.assert_array_equal(lut[codes], x)
    assert snr_db(x, lut[codes]) == float("inf")


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="finite"):
        lloyd_quantizer(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="levels"):
        lloyd_quantizer(np.ones(3), levels=1)
