"""Exact integrals of Rd over triangles and vertex cells: against brute-force grids, the
tabulated G against the closed form, and the plane's cells summing to the disc integral."""

import numpy as np
import pytest
from fixtures import plane

from sssbake.pipeline.core.cell_integral import Cumulative, apex_triangle, cell_integral, triangle_integral_in_plane
from sssbake.pipeline.core.profile import classical_dipole, diffuse_reflectance_profile, disc_integral, profile_for
from sssbake.pipeline.core.materials import preset, preset_names

P = classical_dipole([1.0, 2.19, 0.3], [0.5, 0.0021, 0.01], 1.4)


def grid_integral(point, a, b, c, n=1200):
    """∫ Rd(|p - point|) over the triangle by the midpoint rule in barycentric coordinates."""
    u, v = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n)
    inside = u + v <= 1.0
    p = a + u[inside, None] * (b - a) + v[inside, None] * (c - a)
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a))
    return diffuse_reflectance_profile(np.linalg.norm(p - point, axis=1), P).mean(axis=0) * area


@pytest.mark.parametrize("seed", range(4))
def test_triangles_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    a, b, c = (np.r_[rng.normal(size=2) * 1.5, 0.0] for _ in range(3))
    beside = np.r_[rng.normal(size=2) * 1.5, 0.0]  # anywhere in the plane, inside or out
    table = Cumulative.build(P)
    expected = grid_integral(a, a, b, c)
    np.testing.assert_allclose(apex_triangle(a[None], b[None], c[None], table)[0], expected, rtol=2e-3)
    np.testing.assert_allclose(triangle_integral_in_plane(beside[None], a[None], b[None], c[None], table)[0],
                               grid_integral(beside, a, b, c), rtol=5e-3)


def test_cumulative_table_matches_closed_form():
    r = np.exp(np.random.default_rng(0).uniform(np.log(1e-9), np.log(1e7), 5000))
    for name in preset_names():
        p = profile_for(preset(name))
        np.testing.assert_allclose(Cumulative.build(p)(r), disc_integral(r, p), rtol=1e-5)


def test_plane_cells_and_flat_triangles():
    # The cells of a regular plane tile it: each is a hexagon-like polygon of the vertex's area;
    # its integral lies between those of the inscribed and the equal-area disc.
    verts, faces, centre = plane(1.0, 3)
    own = cell_integral(verts, faces, P)[centre]
    assert np.all(own < disc_integral(np.sqrt(1.0 / np.pi), P))  # a disc is the most compact shape
    assert np.all(own > disc_integral(0.5 * np.sqrt(0.5), P))
    # A flat triangle (apex on the edge's line) holds nothing; an unused vertex gets 0.
    line = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    assert np.all(apex_triangle(line[:1], line[1:2], line[2:], Cumulative.build(P)) == 0.0)
    assert np.all(cell_integral(np.vstack([verts, [[9.0, 9.0, 0.0]]]), faces, P)[-1] == 0.0)



def test_channels_are_the_call_channel_first():
    r = np.random.default_rng(2).random((7, 5)) * 4.0
    table = Cumulative.build(P)
    np.testing.assert_array_equal(table.channels(r), np.moveaxis(table(r), -1, 0))


@pytest.mark.parametrize("seed", range(3))
def test_compiled_rule_equals_the_polar_quadrature(seed):
    # The compiled rule (atan2 angles, G_i e^(f·slope) by a Taylor polynomial) against the polar
    # Gauss-Legendre sum written out with the numpy G (`Cumulative.__call__`): equal to rounding,
    # for triangles from needle-thin to wide, and from tiny (below G's table) to far beyond it.
    rng = np.random.default_rng(seed)
    p = profile_for(preset("skin2"))
    table = Cumulative.build(p)
    scale = np.exp(rng.uniform(np.log(1e-6), np.log(50.0), 200))[:, None]
    apex, e1, e2 = (rng.normal(size=(200, 3)) * scale for _ in range(3))
    e2[:20] = e1[:20] * 3.0 + 1e-4 * e2[:20]  # needles
    x, w = np.polynomial.legendre.leggauss(8)
    double_area = np.linalg.norm(np.cross(e1, e2), axis=1)
    angle = np.arctan2(double_area, np.einsum("ij,ij->i", e1, e2))
    edge = e2 - e1
    length = np.linalg.norm(edge, axis=1)
    along = -np.einsum("ij,ij->i", e1, edge) / length
    foot = double_area / length
    to_foot = np.arctan2(np.abs(along), foot) * np.sign(along)
    phi = 0.5 * angle[:, None] * (x + 1.0)
    rho = foot[:, None] / np.cos(phi - to_foot[:, None])
    expected = np.einsum("k,mkc->mc", w, table(rho)) * (angle / (4.0 * np.pi))[:, None]
    got = apex_triangle(apex, apex + e1, apex + e2, table, nodes=8)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())
