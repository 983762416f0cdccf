"""Lloyd-Max quantiser: optimality conditions, closed-form SNR, degenerate inputs."""

import numpy as np
import pytest

from sssbake.pipeline.techniques.prt.lloyd import lloyd_quantizer, snr_db


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


def test_distortion_never_increases_over_iterations():
    x = np.random.default_rng(3).lognormal(sigma=1.5, size=50_000)
    mse = []
    for it in range(0, 12):
        lut, codes = lloyd_quantizer(x, levels=8, iterations=it, tol=0.0)
        mse.append(np.mean((x - lut[codes]) ** 2))
    assert all(b <= a * (1 + 1e-12) for a, b in zip(mse, mse[1:])), mse
    assert mse[-1] < mse[0]


def test_weights_pull_levels_towards_the_important_values():
    x = np.random.default_rng(4).random(100_000)
    w = np.where(x < 0.5, 10.0, 1.0)
    lut, codes = lloyd_quantizer(x, levels=16, weights=w)
    assert np.sum(lut < 0.5) > 8  # denser where the weight is
    means = np.bincount(codes, weights=w * x, minlength=16) / np.bincount(codes, weights=w, minlength=16)
    np.testing.assert_allclose(lut, means, rtol=1e-3)  # weighted centroids
    plain, _ = lloyd_quantizer(x, levels=16)
    weighted_error = lambda l: np.sum(w * (x - l[np.abs(x[:, None] - l).argmin(axis=1)]) ** 2)  # noqa: E731
    assert weighted_error(lut) < weighted_error(plain)


def test_large_inputs_are_subsampled_for_the_fit_and_fully_encoded(monkeypatch):
    import sssbake.pipeline.techniques.prt.lloyd as lloyd

    monkeypatch.setattr(lloyd, "FIT_SAMPLE", 5_000)
    x = np.random.default_rng(5).normal(size=(40_000,)).astype(np.float32)
    lut, codes = lloyd_quantizer(x, levels=64)
    nearest = np.searchsorted(0.5 * (lut[1:] + lut[:-1]), x.astype(np.float64), side="right")
    np.testing.assert_array_equal(codes, nearest)  # every value to its nearest level
    assert snr_db(x, lut[codes]) > 25.0  # 6 bits: ~6 dB per bit even from a 5k sample


def test_sixteen_bit_codes():
    x = np.random.default_rng(6).random(20_000)
    lut, codes = lloyd_quantizer(x, levels=1024, iterations=5)
    assert codes.dtype == np.uint16 and lut.shape == (1024,)
    assert snr_db(x, lut[codes]) > 50.0


def test_few_distinct_values_are_exact():
    x = np.array([[3.0, 1.0], [1.0, 2.0]])
    lut, codes = lloyd_quantizer(x)
    np.testing.assert_array_equal(lut[codes], x)
    assert snr_db(x, lut[codes]) == float("inf")


def test_constant_data_is_exact():
    lut, codes = lloyd_quantizer(np.full((4, 5), 0.25))
    np.testing.assert_array_equal(lut[codes], 0.25)
    assert np.all(np.isfinite(lut))


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="finite"):
        lloyd_quantizer(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="levels"):
        lloyd_quantizer(np.ones(3), levels=1)
    with pytest.raises(ValueError, match="weights"):
        lloyd_quantizer(np.ones(3), weights=np.array([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="weights are zero"):
        lloyd_quantizer(np.ones(3), weights=np.zeros(3))


def test_compiled_encoding_and_distortion_are_the_numpy_definitions():
    # `_encode` and `_distortion` are compiled; the numpy forms they replaced, value for value
    import sssbake.pipeline.techniques.prt.lloyd as lloyd

    rng = np.random.default_rng(8)
    sample = np.sort(np.round(rng.lognormal(size=20_000), 2))  # ties on the midpoints too
    w = rng.random(sample.shape)
    for levels in (2, 7, 256, 1000):
        lut = np.sort(rng.choice(sample, levels))
        mid = 0.5 * (lut[1:] + lut[:-1])
        nearest = np.searchsorted(mid, sample, side="right")
        for values in (sample, sample.astype(np.float32), (sample * 10).astype(np.int64)):
            expected = np.searchsorted(mid, values.astype(np.float64), side="right")
            np.testing.assert_array_equal(lloyd._encode(values, lut, np.uint16), expected)
        bounds = lloyd._cells(sample, lut)
        terms = np.empty(len(sample))
        assert lloyd._distortion(sample, w, lut, bounds, np.sum(w), terms) == float(
            np.sum(w * (sample - lut[nearest]) ** 2) / np.sum(w))
