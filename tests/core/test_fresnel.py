import numpy as np
import pytest

from sssbake.pipeline.core.fresnel import fresnel_transmittance, schlick_transmittance


def test_normal_incidence_closed_form():
    for eta in (1.0, 1.3, 1.5, 2.0):
        f0 = ((eta - 1) / (eta + 1)) ** 2
        np.testing.assert_allclose(fresnel_transmittance(eta, 1.0), 1 - f0, rtol=1e-12)
        np.testing.assert_allclose(schlick_transmittance(eta, 1.0), 1 - f0, rtol=1e-12)


def test_brewster_angle_has_no_p_reflection():
    # At Brewster's angle tan θ = η the p-polarised reflectance vanishes: R = Rs / 2.
    eta = 1.5
    theta = np.arctan(eta)
    ci = np.cos(theta)
    ct = np.sqrt(1 - np.sin(theta) ** 2 / eta**2)
    rs = ((ci - eta * ct) / (ci + eta * ct)) ** 2
    np.testing.assert_allclose(1 - fresnel_transmittance(eta, ci), rs / 2, rtol=1e-12)


@pytest.mark.parametrize("eta", [1.0, 1.33, 2.0])
def test_range_and_grazing(eta):
    c = np.linspace(-1, 1, 2001)
    for f in (fresnel_transmittance, schlick_transmittance):
        t = f(eta, c)
        assert np.all(np.isfinite(t)) and np.all((t >= 0) & (t <= 1))
        assert np.all(t[c <= 0] == 0.0)
    if eta > 1:
        # Transmission falls monotonically towards grazing incidence.
        t = fresnel_transmittance(eta, c[c > 0])
        assert np.all(np.diff(t) >= -1e-15)


def test_schlick_close_to_exact():
    c = np.linspace(0.05, 1, 200)
    # Schlick is known to be off by a few percent near grazing incidence, no more.
    assert np.max(np.abs(schlick_transmittance(1.5, c) - fresnel_transmittance(1.5, c))) < 0.04
