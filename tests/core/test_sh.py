"""Real spherical harmonics: orthonormal, the convention pinned, exact fits of band-limited signals."""

import numpy as np
import pytest
from scipy.special import sph_harm_y

from sssbake.pipeline.core.directions import direction_set, fibonacci_sphere
from sssbake.pipeline.core.sh import MAX_ORDER, sh_basis, sh_fit_matrix, sh_project


def test_basis_is_orthonormal():
    d = fibonacci_sphere(100_000)
    b = sh_basis(d, MAX_ORDER)
    gram = b.T @ b * (4.0 * np.pi / len(d))
    np.testing.assert_allclose(gram, np.eye(MAX_ORDER**2), atol=1e-5)


def test_convention_is_real_parts_of_the_condon_shortley_harmonics():
    w = np.random.default_rng(0).normal(size=(20, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    theta, phi = np.arccos(w[:, 2]), np.arctan2(w[:, 1], w[:, 0])
    b = sh_basis(w, MAX_ORDER)
    for l in range(MAX_ORDER):
        for m in range(-l, l + 1):
            c = sph_harm_y(l, abs(m), theta, phi)
            expected = c.real if m == 0 else np.sqrt(2.0) * (c.real if m > 0 else c.imag)
            np.testing.assert_allclose(b[:, l * l + l + m], expected, atol=1e-12)
    # the first bands in closed form
    np.testing.assert_allclose(b[:, 0], 0.5 / np.sqrt(np.pi))
    np.testing.assert_allclose(b[:, 2], np.sqrt(3.0 / (4.0 * np.pi)) * w[:, 2])


@pytest.mark.parametrize("order", [1, 3, 5])
def test_band_limited_signals_are_fitted_exactly_and_error_falls_with_order(order):
    d = fibonacci_sphere(200)
    coeffs = np.random.default_rng(order).normal(size=order**2)
    values = sh_basis(d, order) @ coeffs
    np.testing.assert_allclose(sh_fit_matrix(d, order) @ values, coeffs, atol=1e-10)


def test_fit_error_falls_with_order():
    d = fibonacci_sphere(200)
    values = np.clip(d @ np.array([0.2, 0.3, 0.93]), 0.0, None) ** 2  # a clamped lobe, not band-limited
    errors = [np.sqrt(np.mean((sh_basis(d, n) @ (sh_fit_matrix(d, n) @ values) - values) ** 2)) for n in range(1, 9)]
    assert all(b < a for a, b in zip(errors, errors[1:])), errors


def test_project_takes_a_direction_set_and_batches():
    ds = direction_set(100, lookup_size=8)
    coeffs = np.random.default_rng(7).normal(size=(3, 5, 16))
    values = coeffs @ sh_basis(ds.directions, 4).T  # (3, 5, K)
    np.testing.assert_allclose(sh_project(values, ds, 4), coeffs, atol=1e-10)
    np.testing.assert_allclose(sh_project(values, ds.directions, 4), coeffs, atol=1e-10)


def test_least_squares_beats_quadrature_on_few_directions():
    d = fibonacci_sphere(64)
    values = np.clip(d @ np.array([0.3, 0.4, 0.866]), 0.0, None) ** 1.5
    for order in (3, 5, 7):
        err = {m: np.sqrt(np.mean((sh_basis(d, order) @ sh_project(values, d, order, m) - values) ** 2))
               for m in ("lsq", "quadrature")}
        assert err["lsq"] <= err["quadrature"] * (1 + 1e-9), (order, err)
    # on band-limited data quadrature on Fibonacci points is inexact, least squares exact
    coeffs = np.random.default_rng(2).normal(size=25)
    values = sh_basis(d, 5) @ coeffs
    assert np.abs(sh_project(values, d, 5, "quadrature") - coeffs).max() > 1e-3
    np.testing.assert_allclose(sh_project(values, d, 5, "lsq"), coeffs, atol=1e-10)


def test_orders_out_of_range_are_refused():
    with pytest.raises(ValueError, match="order must be in"):
        sh_basis(np.array([[0.0, 0.0, 1.0]]), MAX_ORDER + 1)
    with pytest.raises(ValueError, match="cannot determine"):
        sh_fit_matrix(fibonacci_sphere(8), 3)
    with pytest.raises(ValueError, match="method"):
        sh_project(np.ones(8), fibonacci_sphere(8), 2, "exact")
    with pytest.raises(ValueError, match="axis of 8 directions"):
        sh_project(np.ones(7), fibonacci_sphere(8), 2)
