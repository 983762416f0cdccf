"""Stability at the extremes, encodings (hypothesis): the glTF normalized quantizers, the kernels'
codes, prt's int8 coefficients, Lloyd's quantiser and the SH fits never overflow their encodings
and decode within their stated error for any finite input, from 1e-30 to 1e30."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from sssbake.exporters.gltf import dequantize, quantize
from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.sh import sh_project
from sssbake.pipeline.techniques.kernels.layout import decode_kernels, encode_kernels, kernel_error_bound
from sssbake.pipeline.techniques.prt.compress import encode_int8, int8_scales
from sssbake.pipeline.techniques.prt.decode import decode_int8
from sssbake.pipeline.techniques.prt.lloyd import lloyd_quantizer

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
magnitudes = st.floats(-30.0, 30.0).map(lambda e: float(10.0**e))


def scaled(shape, unit=False):
    """Arrays of `shape` in [-1, 1] times a magnitude from 1e-30 to 1e30 (or in [-1, 1])."""
    base = arrays(np.float64, shape, elements=st.floats(-1.0, 1.0))
    return base if unit else st.tuples(base, magnitudes).map(lambda t: t[0] * t[1])


@FAST
@given(scaled((40, 3), unit=True), st.sampled_from(["snorm8", "snorm16", "unorm8", "unorm16"]))
def test_normalized_quantizers_round_trip_within_half_a_step(values, encoding):
    if encoding.startswith("unorm"):
        values = np.abs(values)
    stored = quantize(values, encoding)
    top = np.iinfo(stored.dtype).max
    back = dequantize(stored, True)
    assert np.all(np.abs(back - values) <= 0.5 / top + 1e-12)
    with pytest.raises(ValueError, match="needs values in"):
        quantize(values + 2.0, encoding)


@FAST
@given(scaled((5, 9, 3)), st.sampled_from([8, 16]))
def test_kernel_codes_never_overflow_and_hold_their_bound(kernels, bits):
    kernels = kernels.astype(np.float32)
    codes, scales = encode_kernels(kernels, bits)
    top = 2 ** (bits - 1) - 1
    assert codes.dtype == (np.int8 if bits == 8 else np.int16) and np.abs(codes.astype(np.int64)).max() <= top
    decoded = decode_kernels(codes, scales, bits)
    assert np.all(np.isfinite(decoded))
    bound = kernel_error_bound(scales, bits)[:, None, :]
    # the float32 of the kernels and of the decode add their own rounding at large magnitudes
    assert np.all(np.abs(decoded.astype(np.float64) - kernels) <= bound * 1.001 + 1e-7 * np.abs(kernels))


@FAST
@given(scaled((30, 3, 4)))
def test_prt_int8_coefficients_never_overflow(coeffs):
    scale = int8_scales(coeffs)
    assert np.all(np.isfinite(scale)) and np.all(scale > 0)
    codes = encode_int8(coeffs, scale)
    assert codes.dtype == np.int8 and np.abs(codes.astype(np.int64)).max() <= 127
    decoded = decode_int8(codes, scale)
    assert np.all(np.isfinite(decoded))
    # with the largest magnitude as the range nothing clips: error within half a step
    full = int8_scales(coeffs, 100.0)
    error = np.abs(decode_int8(encode_int8(coeffs, full), full) - coeffs)
    assert np.all(error <= 0.5 * full.astype(np.float64) / 127 * 1.0001 + 1e-300)


@FAST
@given(scaled((500,)))
def test_lloyd_codes_stay_in_range_and_decode_to_levels_inside_the_data(values):
    lut, codes = lloyd_quantizer(values, levels=16)
    assert np.all(np.isfinite(lut)) and len(lut) <= 16
    assert codes.min() >= 0 and codes.max() < len(lut)
    assert lut.min() >= values.min() - 1e-12 * abs(values.min()) and lut.max() <= values.max() + 1e-12 * abs(values.max())


@FAST
@given(magnitudes, st.integers(1, 6))
def test_sh_fits_of_bounded_signals_stay_finite_and_reproduce_band_limited_ones(magnitude, order):
    ds = direction_set(64)
    x, y, z = ds.directions.T
    signal = magnitude * (0.5 + 0.3 * z - 0.2 * x * y)  # order 3 (l <= 2)
    coeffs = sh_project(signal, ds, order)
    assert np.all(np.isfinite(coeffs))
    if order >= 3:  # least squares is exact for a band-limited signal
        from sssbake.pipeline.core.sh import sh_basis

        np.testing.assert_allclose(sh_basis(ds.directions, order) @ coeffs, signal, rtol=1e-9,
                                   atol=1e-9 * magnitude)
