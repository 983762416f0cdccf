import numpy as np
import pytest
from fixtures import plane
from scipy import integrate

from sssbake.pipeline.core.profile import (
    Profile,
    boundary_a,
    classical_dipole,
    diffuse_reflectance_profile,
    disc_integral,
    exit_normalisation,
    fresnel_diffuse_reflectance,
    profile_derivatives,
    profile_for,
    profile_of,
    profile_total,
    radius_for_energy,
    radius_holding,
    total_for_albedo,
    total_reflectance,
)
from sssbake.pipeline.core.materials import preset, preset_names


def _quad_total(p: Profile) -> np.ndarray:
    """2π ∫_0^∞ Rd(r) r dr by adaptive quadrature in log r: independent of the closed forms."""
    out = []
    for c in range(3):
        def f(t, c=c):
            r = np.exp(t)
            return 2 * np.pi * diffuse_reflectance_profile(np.array([r]), p)[0, c] * r * r

        w, z, s = p.channel(c)
        lo, hi = np.log(z.min()) - 40.0, np.log(z.max()) + 60.0
        # Split at the poles' depths and decay lengths, where the integrand changes shape.
        pts = sorted(set(np.log(z)) | set(-np.log(s[s > 0])))
        pts = [x for x in pts if lo < x < hi]
        val, _ = integrate.quad(f, lo, hi, points=pts, limit=500, epsabs=0, epsrel=1e-11)
        out.append(val)
    return np.array(out)


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
@pytest.mark.parametrize("name", preset_names())
def test_presets_integral_matches_closed_form(name, model):
    p = profile_for(preset(name, model))
    closed = profile_total(p)
    np.testing.assert_allclose(_quad_total(p), closed, rtol=1e-6)
    np.testing.assert_allclose(disc_integral(np.full(3, 1e12), p).diagonal(), closed, rtol=1e-9)


EXTREMES = [
    (alpha, eta, st)
    for alpha in (1e-6, 0.5, 0.99, 1 - 1e-9)
    for eta in (1.0, 1.3, 2.0)
    for st in (1e-3, 1.0, 1e4)
]


@pytest.mark.parametrize("alpha,eta,st", EXTREMES)
def test_extremes_integral_matches_closed_form_and_finite(alpha, eta, st):
    s = np.full(3, alpha * st)
    a = np.full(3, (1 - alpha) * st)
    p = classical_dipole(s, a, eta)
    closed = total_for_albedo(np.full(3, alpha), eta, "dipole")
    np.testing.assert_allclose(_quad_total(p), closed, rtol=1e-6)
    r = np.concatenate([[0.0], np.logspace(-12, 12, 200) / st])
    prof = diffuse_reflectance_profile(r, p)
    disc = disc_integral(r, p)
    assert np.all(np.isfinite(prof)) and np.all(prof >= 0)
    assert np.all(np.isfinite(disc)) and np.all(disc >= 0)
    assert np.all(np.diff(disc[:, 0]) >= -1e-15 * closed[0])  # monotone in the radius
    assert np.all(disc <= closed * (1 + 1e-12))


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
def test_disc_integral_derivative_is_profile(model):
    p = profile_for(preset("skin1", model))
    a = np.array([0.01, 0.3, 2.0, 10.0])
    h = 1e-6
    num = (disc_integral(a + h, p) - disc_integral(a - h, p)) / (2 * h)
    np.testing.assert_allclose(num, 2 * np.pi * a[:, None] * diffuse_reflectance_profile(a, p), rtol=1e-6, atol=1e-9)


def test_disc_integral_small_radius_has_no_cancellation():
    # For a << z the integral is π a² Rd(0) to leading order; the naive difference loses all digits.
    p = profile_for(preset("marble"))
    a = 1e-7
    np.testing.assert_allclose(disc_integral(a, p), np.pi * a * a * diffuse_reflectance_profile(0.0, p), rtol=1e-6)


@pytest.mark.parametrize("eta", [1.0, 1.1, 1.3, 1.5, 2.0])
def test_fresnel_fit_matches_exact_internal_diffuse_reflectance(eta):
    """F_dr fits the hemispherical average of the exact Fresnel reflectance seen from inside.

    Inside at cosine c, Snell gives the outside cosine; by reciprocity the internal reflectance
    equals the external one there, and beyond the critical angle it is 1 (total internal reflection).
    """
    from sssbake.pipeline.core.fresnel import fresnel_transmittance

    def internal_reflectance(c):
        s2 = (1 - c * c) * eta * eta
        return 1.0 if s2 >= 1 else 1.0 - float(fresnel_transmittance(eta, np.sqrt(1 - s2)))

    crit = np.sqrt(max(0.0, 1 - 1 / eta**2))
    exact, _ = integrate.quad(lambda c: 2 * c * internal_reflectance(c), 0, 1, points=[crit] if crit > 0 else None, limit=200)
    assert abs(fresnel_diffuse_reflectance(eta) - exact) < 2e-3
    fdr = fresnel_diffuse_reflectance(eta)
    np.testing.assert_allclose(boundary_a(eta), (1 + fdr) / (1 - fdr))


def test_no_absorption_limit():
    # σ_a = 0: R_d = α'/2 (1 + 1) = 1, the energy bound; the radius must come from energy, not e^(-σ_tr r).
    p = classical_dipole(np.ones(3), np.zeros(3), 1.3)
    np.testing.assert_allclose(total_for_albedo(p.alpha_prime, 1.3, "dipole"), 1.0)
    r = radius_for_energy(0.01, p)
    assert np.all(np.isfinite(r))
    np.testing.assert_allclose(disc_integral(r, p).diagonal(), 0.99, rtol=1e-9)


def test_radius_for_energy_bounds_dropped_fraction():
    for name in ("marble", "ketchup", "skin1"):
        p = profile_for(preset(name))
        rd = profile_total(p)
        r = radius_for_energy(1e-3, p)
        np.testing.assert_allclose(disc_integral(r, p).diagonal(), 0.999 * rd, rtol=1e-9)


def test_radius_for_energy_is_the_bisection_of_the_disc_integral():
    """All 200 halvings of `disc_integral` per channel: the same bits (the bisection stops once lo
    and hi are neighbours, and takes each channel's poles at its own radius only)."""
    for name in ("marble", "ketchup", "skin1", "wholemilk"):
        p = profile_for(preset(name))
        for dropped in (1e-1, 1e-3, 1e-6):
            target = (1.0 - dropped) * profile_total(p)
            lo, hi = np.zeros(3), np.full(3, 1e12)
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                enough = np.diagonal(disc_integral(mid, p)) >= target
                hi, lo = np.where(enough, mid, hi), np.where(enough, lo, mid)
            np.testing.assert_array_equal(radius_for_energy(dropped, p), hi)


def _plane_response(p: Profile, spacing: float, half: int) -> np.ndarray:
    """Radiant exitance at the centre vertex of a regular triangulated plane under uniform unit
    irradiance, from the discrete per-vertex sums: Σ_j Rd(|x_j - x_0|) A_j + the self disc term."""
    verts, faces, centre = plane(spacing, half)
    from sssbake.pipeline.core.surface import vertex_areas

    areas = vertex_areas(verts, faces)
    dist = np.linalg.norm(verts - verts[centre], axis=1)
    others = np.arange(len(verts)) != centre
    gathered = (diffuse_reflectance_profile(dist[others], p) * areas[others, None]).sum(axis=0)
    own = disc_integral(np.sqrt(areas[centre] / np.pi), p)
    return gathered + own


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
def test_flat_plane_reproduces_total_diffuse_reflectance(model):
    m = preset("skin1", model)
    p = profile_for(m)
    rd = profile_total(p)
    reach = radius_for_energy(1e-4, p).max()
    spacing = 0.25 * m.mean_free_path_mm.min()
    half = int(np.ceil(reach / spacing))
    got = _plane_response(p, spacing, half)
    np.testing.assert_allclose(got, rd, rtol=0.01 if model == "dipole" else 0.03)


@pytest.mark.parametrize("spacing_mfp", [0.25, 2.0])
def test_flat_plane_reproduces_total_with_cell_averages(spacing_mfp):
    # point sums under-resolve the Monte Carlo profile's shallow poles (light scattered a few times,
    # within ~1/100 of a mean free path: 3 % low above); the bake's cell integrals (`NearField`) do not
    from sssbake.pipeline.core.near_field import NearField

    m = preset("skin1")
    p = profile_for(m)
    spacing = spacing_mfp * m.mean_free_path_mm.min()
    half = int(np.ceil(radius_for_energy(1e-4, p).max() / spacing))
    verts, faces, centre = plane(spacing, half)
    field = NearField.build(verts, faces, np.tile([0.0, 0.0, 1.0], (len(verts), 1)), p)
    sources = np.arange(len(verts))
    got = field.weights(np.full(len(verts), centre), sources).sum(axis=0)
    np.testing.assert_allclose(got, profile_total(p), rtol=0.01)


@pytest.mark.parametrize("alpha", [0.0, 1e-6, 0.02, 0.5, 0.99, 1 - 1e-9, 1.0])
@pytest.mark.parametrize("eta", [1.0, 1.33, 2.0])
def test_montecarlo_extremes_are_finite_and_conserve(alpha, eta):
    st = 3.0
    p = profile_of((alpha * st,) * 3, ((1 - alpha) * st,) * 3, eta, "montecarlo")
    total = total_reflectance(p)
    assert np.all((total >= 0) & (total <= 1.0 + 1e-12))
    if alpha == 0.0:
        assert np.all(total == 0.0)
    r = np.concatenate([[0.0], np.logspace(-9, 9, 200) / st])
    prof, disc = diffuse_reflectance_profile(r, p), disc_integral(r, p)
    assert np.all(np.isfinite(prof)) and np.all(prof >= 0)
    assert np.all(np.isfinite(disc)) and np.all(np.diff(disc[:, 0]) >= -1e-15)
    # the last radius, 3e8 mean free paths out, leaves a heavy tail's z/r (no absorption) behind
    np.testing.assert_allclose(disc[-1], profile_total(p), rtol=1e-5, atol=1e-300)
    for c in range(3):
        assert all(np.all(np.isfinite(v)) for v in profile_derivatives(r, p, c))


def test_exit_normalisation_is_the_hemispherical_fresnel_transmittance():
    # c(η) = 1 - F_dr(outside): 1 without a boundary; by reciprocity
    # n² (1 - F_dr,inside) = 1 - F_dr,outside (Egan & Hilgeman's relation), F_dr,inside by quadrature
    from sssbake.pipeline.core.fresnel import fresnel_transmittance

    assert exit_normalisation(1.0) == pytest.approx(1.0, abs=1e-12)
    for eta in (1.2, 1.5, 2.0):
        def reflectance_inside(mu):  # beyond the critical angle: total internal reflection
            s2 = eta * eta * (1.0 - mu * mu)
            return 1.0 if s2 >= 1.0 else 1.0 - float(fresnel_transmittance(eta, np.sqrt(1.0 - s2)))

        critical = np.sqrt(1.0 - 1.0 / eta**2)
        inside = integrate.quad(lambda mu: 2.0 * mu * reflectance_inside(mu), 0.0, 1.0, points=[critical])[0]
        assert exit_normalisation(eta) == pytest.approx(eta * eta * (1.0 - inside), rel=1e-6)


def test_montecarlo_profile_is_radiance_normalised():
    # the values a runtime multiplies by F_t(η, ω_o)/π integrate to c(η) · profile_total: the light
    # leaving a flat medium is the total reflectance itself
    m = preset("marble")
    p = profile_for(m)
    np.testing.assert_allclose(profile_total(p) * exit_normalisation(m.eta), total_reflectance(p), rtol=1e-12)
    d = profile_for(preset("marble", "dipole"))
    np.testing.assert_allclose(profile_total(d), total_reflectance(d), rtol=1e-12)


@pytest.mark.parametrize("model", ["montecarlo", "dipole"])
def test_escape_gain_scales_every_value_and_the_total(model):
    from dataclasses import replace

    m = preset("skin1", model)
    gain = np.array([1.3, 1.2, 1.1])
    half, gained = profile_for(m), profile_for(replace(m, escape_gain=tuple(gain)))
    r = np.geomspace(1e-3, 30.0, 50)
    np.testing.assert_allclose(diffuse_reflectance_profile(r, gained), diffuse_reflectance_profile(r, half) * gain,
                               rtol=1e-12)
    np.testing.assert_allclose(total_reflectance(gained), total_reflectance(half) * gain, rtol=1e-12)
    np.testing.assert_allclose(radius_holding(gained, 0.5), radius_holding(half, 0.5), rtol=1e-6)  # the shape stays
