import numpy as np
import pytest

from sssbake.pipeline.core.profile import diffuse_reflectance_profile, profile_for, profile_total
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.techniques.screen.samples import ScreenSamplesOptions, screen_samples


@pytest.mark.parametrize("name", ["skin1", "marble", "ketchup"])
def test_the_gather_over_a_uniformly_lit_plane_tends_to_r_d(name):
    # Σ Rd_c(r_i) w_i estimates ∫ Rd_c dA = R_d per channel; over seeds its mean converges
    p = profile_for(preset(name))
    expected = profile_total(p)
    estimates = []
    for seed in range(160):
        s = screen_samples(preset(name), ScreenSamplesOptions(samples=64, uniform=16, seed=seed))
        r = np.linalg.norm(s.offsets, axis=1)
        estimates.append(diffuse_reflectance_profile(r, p).T @ s.weights)
    estimates = np.array(estimates)
    assert np.allclose(estimates.mean(axis=0), expected, rtol=0.01)
    # a third of the importance samples per channel: every channel, however narrow, has little noise
    # (ketchup's blue had 22 % with red's samples alone; the Monte Carlo profile's skin1 red, whose
    # near-field peak and far tail the other channels' samples cover thinly, measured 5.0 %)
    assert np.all(estimates.std(axis=0) / expected < 0.06)


def test_sample_sets_and_weights():
    s = screen_samples(preset("skin1"), ScreenSamplesOptions(samples=50, uniform=10))
    assert s.offsets.shape == (60, 2) and np.all(np.isfinite(s.weights)) and np.all(s.weights > 0)
    assert s.driver == 0  # skin scatters red furthest
    assert np.all(np.linalg.norm(s.offsets[50:], axis=1) <= s.uniform_radius_mm)


@pytest.mark.parametrize("bound", [1e-2, 1e-3, 1e-4])
def test_rd_table_meets_its_bound_checked_densely(bound):
    p = profile_for(preset("marble"))
    s = screen_samples(preset("marble"), ScreenSamplesOptions(table_error=bound))
    size = s.table.shape[1]
    t = np.linspace(0.0, 1.0, 20 * size)
    read = np.array([np.interp(t, np.linspace(0, 1, size), row) for row in s.table])
    exact = diffuse_reflectance_profile(s.table_reach_mm * t * t, p).T
    relevant = exact >= 1e-6 * exact[:, :1]
    assert np.max(np.abs(read - exact)[relevant] / exact[relevant]) <= bound * 1.0001
    assert s.table_error <= bound
    # the smallest size that holds it: half as many entries would not
    if size > 64:
        t = np.linspace(0.0, 1.0, size // 2)
        mid = 0.5 * (t[1:] + t[:-1])
        values = diffuse_reflectance_profile(s.table_reach_mm * t * t, p).T
        exact = diffuse_reflectance_profile(s.table_reach_mm * mid * mid, p).T
        linear = 0.5 * (values[:, 1:] + values[:, :-1])
        relevant = exact >= 1e-6 * values[:, :1]
        assert np.max(np.abs(linear - exact)[relevant] / exact[relevant]) > bound


def test_bad_options_raise():
    with pytest.raises(ValueError, match="screen: samples"):
        ScreenSamplesOptions(samples=0).check()
    with pytest.raises(ValueError, match="screen: table_error"):
        ScreenSamplesOptions(table_error=0.5).check()
