"""Rd averaged over a source disc: exact quadrature against a brute-force grid, the table
against the exact mean, and the limits (a point, the disc's own centre)."""

import numpy as np
import pytest

from sssbake.pipeline.core.profile import classical_dipole, diffuse_reflectance_profile, disc_integral, profile_for
from disc_reference import disc_expansion, disc_mean, disc_mean_exact

from sssbake.pipeline.core.disc_average import DiscMean
from sssbake.pipeline.core.materials import preset

# Strongly absorbing, marble-like and nearly non-absorbing channels in one material.
P = classical_dipole([1.0, 2.19, 0.3], [0.5, 0.0021, 0.01], 1.4)


def grid_mean(d: float, a: float, h: float = 0.0, n: int = 900) -> np.ndarray:
    """Mean of Rd over the disc, the receiver h above its plane, by the midpoint rule on an n×n
    grid (error ~1e-4 here)."""
    g = ((np.arange(n) + 0.5) / n * 2.0 - 1.0) * a
    xx, yy = np.meshgrid(g, g)
    inside = xx**2 + yy**2 <= a * a
    return diffuse_reflectance_profile(np.sqrt((xx[inside] - d) ** 2 + yy[inside] ** 2 + h * h), P).mean(axis=0)


@pytest.mark.parametrize("a", [0.05, 0.5, 2.0])
@pytest.mark.parametrize("t", [0.0, 0.4, 0.95, 1.0, 1.05, 2.0, 6.0])
def test_exact_mean_matches_brute_force(a, t):
    got = disc_mean_exact(np.array([t * a]), np.array([a]), P)[0]
    np.testing.assert_allclose(got, grid_mean(t * a, a), rtol=3e-4)


@pytest.mark.parametrize("a", [0.2, 1.0])
@pytest.mark.parametrize("t, lift", [(0.0, 0.3), (0.0, 1.0), (0.5, 0.6), (2.0, 1.0), (5.0, 4.0), (20.0, 6.0)])
def test_tilted_disc(a, t, lift):
    # Across a thin part or a fold: the receiver `lift`·a above the source's plane. The planar
    # disc at the same distance would cover the receiver and be far too bright.
    d, h = t * a, lift * a
    expected = grid_mean(d, a, h)
    np.testing.assert_allclose(disc_mean_exact(d, a, P, h), expected, rtol=3e-4)
    table = DiscMean.build(P, np.array([a]))
    got = disc_mean(table, np.array([np.hypot(d, h)]), np.array([a]), np.array([h]))[0]
    # Beyond the table the expansion's error grows as (σ_tr a)⁴ (1.5⁴ in the absorbing channel).
    assert np.all(np.abs(got / expected - 1) < 3e-3 + (P.sigma_tr * a) ** 4 / 100)


def test_limits():
    # Centred on the receiver: the closed-form disc integral over the disc's area.
    a = np.array([0.01, 0.7, 5.0])
    np.testing.assert_allclose(disc_mean_exact(np.zeros(3), a, P), disc_integral(a, P) / (np.pi * a**2)[:, None],
                               rtol=1e-12)
    # A tiny disc is a point, inside or outside.
    d = np.array([0.0, 0.3, 3.0])
    np.testing.assert_allclose(disc_mean_exact(d, np.full(3, 1e-4), P), diffuse_reflectance_profile(d, P), rtol=1e-6)
    # Far away it is the point value plus the curvature term: error ~(σ_tr a)⁴/200 (4e-5 here).
    table = DiscMean.build(P, np.array([0.2]))
    far = np.array([30.0])
    np.testing.assert_allclose(disc_mean(table, far, np.array([0.2]), np.zeros(1)), disc_mean_exact(far, 0.2, P), rtol=1e-4)
    np.testing.assert_allclose(disc_mean(table, np.ones(1), np.zeros(1), np.zeros(1)), diffuse_reflectance_profile(np.ones(1), P),
                               rtol=1e-12)
    # Far beyond a disc small against 1/σ_tr: the point value, within the spread term it leaves out.
    tiny = DiscMean.build(P, np.array([0.05]))
    d = np.array([5.0])
    exact = disc_mean_exact(d, 0.05, P)
    got = disc_mean(tiny, d, np.array([0.05]), np.zeros(1))
    np.testing.assert_allclose(got, diffuse_reflectance_profile(d, P), rtol=1e-12)
    assert np.all(np.abs(got / exact - 1) < 4e-3)


@pytest.mark.parametrize("model, worst", [("montecarlo", 5e-3), ("dipole", 3e-3)])
@pytest.mark.parametrize("name", ["marble", "skin1", "ketchup", "wholemilk"])
def test_table_matches_exact_mean(name, model, worst):
    # The Monte Carlo profile's shallowest poles (~1/1000 of a mean free path) make ḡ step where
    # the disc's edge crosses the receiver: those pairs take the exact mean (`EDGE_BAND`; 6 % off
    # without); elsewhere its sharper shape costs the bilinear table up to 4e-3 (ketchup).
    p = profile_for(preset(name, model))
    rng = np.random.default_rng(1)
    a = np.exp(rng.uniform(np.log(0.05), np.log(1.0), 4000))
    d = a * rng.uniform(0.0, 8.0, 4000)
    table = DiscMean.build(p, a)
    exact = disc_mean_exact(d, a, p)
    got_all = disc_mean(table, d, a, np.zeros_like(d))
    for c in range(3):
        got = got_all[:, c]
        assert np.all(np.isfinite(got)) and np.all(got > 0)
        assert np.median(np.abs(got / exact[:, c] - 1)) < 2e-4
        assert np.abs(got / exact[:, c] - 1).max() < worst


def test_expansion_matches_its_derivative_form():
    # `disc_expansion` sums e^(-P)/D³ polynomials; it must equal Rd + (a²/8)(Rd''(1 - c²) +
    # Rd'/r (1 + c²)) from `profile_derivatives`, Rd'/r -> Rd'' at r = 0, clipped at 0.
    from sssbake.pipeline.core.profile import profile_derivatives

    rng = np.random.default_rng(5)
    r = np.r_[0.0, 1e-3, rng.random(2000) * 40.0]
    a = rng.random(len(r)) * 3.0
    h = np.minimum(rng.random(len(r)) * 5.0, r)
    c2 = np.divide(h, r, out=np.zeros(len(r)), where=r > 0) ** 2
    expected = np.empty((len(r), 3))
    for c in range(3):
        f, f1, f2 = profile_derivatives(r, P, c)
        slope = np.divide(f1, r, out=f2.copy(), where=r > 0)
        expected[:, c] = np.maximum(f + 0.125 * a**2 * (f2 * (1.0 - c2) + slope * (1.0 + c2)), 0.0)
    got = disc_expansion(r, a, h, P)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12 * expected.max())


def test_the_table_filled_as_pairs_read_it_is_the_exact_mean_at_its_nodes():
    """The kernels fill the table's cells as pairs read them (`scatter_kernels.table_cell`): the
    cells a few pairs read and no others, each ln of the numpy exact mean at its node to rounding;
    the pairs' values the same bits as from the table filled in full first (`log_table`, read-only);
    the table shared with the next build of the same profile and grid, which sees those cells."""
    from sssbake.pipeline.core import disc_average as D
    from sssbake.pipeline.core.near_field import NearField

    rng = np.random.default_rng(3)
    p = profile_for(preset("skin1"))
    # A bumpy 12 × 12 grid: pairs a few radii apart read the table.
    u, v = np.meshgrid(np.arange(12.0), np.arange(12.0))
    x = np.c_[u.ravel(), v.ravel(), 0.05 * rng.standard_normal(144)] * 0.7
    quads = (np.arange(11)[:, None] * 12 + np.arange(11)[None, :]).ravel()
    faces = np.r_[np.c_[quads, quads + 1, quads + 13], np.c_[quads, quads + 13, quads + 12]]
    normals = np.tile([0.0, 0.0, 1.0], (144, 1))
    D._log_table.cache_clear()
    field = NearField.build(x, faces, normals, p)
    table = field.disc.table
    assert np.isnan(table).all()
    o, i = rng.integers(0, 144, 300), rng.integers(0, 144, 300)
    lazy = field.weights(o, i)
    filled = ~np.isnan(table)
    assert filled.any() and not filled.all() and (filled == filled[:1]).all()  # whole cells, all three channels
    ii, jj = np.nonzero(filled[0])
    a, t = field.disc.a[ii], field.disc.t[jj]
    np.testing.assert_allclose(table[:, ii, jj].T, np.log(disc_mean_exact(a * t, a, p)), rtol=1e-12, atol=1e-12)

    again = NearField.build(x, faces, normals, p)
    assert again.disc.table is table  # shared: one bake's readers fill one table
    full = again.disc.log_table
    assert not full.flags.writeable and not np.isnan(full).any()
    assert np.array_equal(full[:, ii, jj], table[:, ii, jj])
    D._log_table.cache_clear()
    prefilled = NearField.build(x, faces, normals, p)
    prefilled.disc.log_table
    assert prefilled.disc.table is not table and np.array_equal(prefilled.disc.table, full)
    assert np.array_equal(prefilled.weights(o, i), lazy)
