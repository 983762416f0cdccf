import numpy as np
import pytest
from scipy import stats
from scipy.integrate import quad

from sssbake.pipeline.core.profile import diffuse_reflectance_profile, profile_for
from sssbake.pipeline.core.profile_sampling import XI_MAX, radius_cdf, sample_radii, solve_u
from sssbake.pipeline.core.materials import preset


@pytest.mark.parametrize("sigma_z", [0.0, 1e-4, 1e-2, 1.0, 30.0, 1e3])
def test_newton_meets_its_tolerance_over_the_whole_range(sigma_z):
    xi = np.array([0.0, 1e-15, 1e-9, 0.3, 0.999, 1 - 1e-9, XI_MAX])
    u = solve_u(xi, sigma_z)
    assert np.all(u >= 1.0) and np.all(np.isfinite(u))
    g = sigma_z * (u - 1.0) + np.log(u) + np.log1p(-xi)
    # relative to the residual's scale at the root (g' u = σz u + 1)
    assert np.all(np.abs(g) <= 1e-12 * (sigma_z * u + 1.0))
    assert u[0] == 1.0


def test_radius_cdf_is_the_profiles_share_of_r_d():
    p = profile_for(preset("skin1"))
    for c in range(3):
        total = quad(lambda s: 2 * np.pi * s * diffuse_reflectance_profile(s, p)[c], 0, np.inf, limit=400)[0]
        for r in (0.1, 1.0, 5.0):
            inside = quad(lambda s: 2 * np.pi * s * diffuse_reflectance_profile(s, p)[c], 0, r, limit=400)[0]
            assert radius_cdf(r, p, c) == pytest.approx(inside / total, rel=1e-8)


@pytest.mark.parametrize("name", ["skin1", "marble", "ketchup"])
def test_samples_follow_rd_times_r(name):
    # Kolmogorov-Smirnov at 1e5 samples against the closed-form CDF
    p = profile_for(preset(name))
    rng = np.random.default_rng(7)
    for c in range(3):
        r = sample_radii(rng.random(100_000), p, c)
        assert stats.kstest(r, lambda x: radius_cdf(x, p, c)).pvalue > 1e-3


def test_bad_numbers_raise():
    with pytest.raises(ValueError, match="profile sampling"):
        solve_u(np.array([1.0]), 1.0)
    with pytest.raises(ValueError, match="profile sampling"):
        solve_u(np.array([0.5]), -1.0)


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
def test_extreme_numbers_give_finite_radii_and_stratification_survives(model):
    p = profile_for(preset("marble", model))
    r = sample_radii(np.array([0.0, 1e-300, 0.5, 1.0 - 1e-16]), p, 1)
    assert r[0] == 0.0 and np.all(np.isfinite(r))
    # ξ → 1 is the far end of the last pole's own CDF (the dipole's last pole, the virtual source,
    # holds the widest tail, so there it is the far end of the whole profile)
    w, z, sigma = p.channel(1)
    u = np.sqrt(r[-1] ** 2 + z[-1] ** 2) / z[-1]
    assert 1.0 - np.exp(-sigma[-1] * z[-1] * (u - 1.0)) / u > 1.0 - 1e-11
    # strata of ξ are strata of each pole's own CDF, 1 - e^(-σz(u - 1)) / u, within its slice of the
    # poles' shares w e^(-σz) (Mertens' real and virtual source for the dipole)
    xi = (np.arange(200) + 0.5) / 200
    r = sample_radii(xi, p, 1)
    w, z, sigma = p.channel(1)
    share = w * np.exp(-sigma * z) / np.sum(w * np.exp(-sigma * z))
    upper = np.cumsum(share)
    k = np.searchsorted(upper, xi, side="right")
    u = np.sqrt(r * r + z[k] ** 2) / z[k]
    term_cdf = 1.0 - np.exp(-sigma[k] * z[k] * (u - 1.0)) / u
    assert np.allclose(term_cdf, (xi - (upper[k] - share[k])) / share[k], atol=1e-9)
