"""Weights of source cells at a receiver: on an irregular plane they tile, so their sum is the
integral of Rd over the plane; far sources fall back to the disc mean; the compiled weights equal
their numpy formulation."""

import numpy as np
import pytest
from disc_reference import disc_expansion, disc_mean, disc_mean_exact, is_point
from scipy.spatial import Delaunay

from sssbake.pipeline.core import scatter_kernels
from sssbake.pipeline.core.cell_integral import triangle_integral_in_plane
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.near_field import ZONE, NearField
from sssbake.pipeline.core.profile import classical_dipole, diffuse_reflectance_profile, disc_integral, profile_for
from sssbake.pipeline.core.surface import area_weighted_normals

P = classical_dipole([1.0, 1.0, 1.0], [0.5, 0.3, 0.2], 1.4)  # z_r = 0.67, 0.77, 0.83 mm
LOW = classical_dipole([1.0, 1.0, 1.0], [0.01, 0.02, 0.03], 1.4)  # long range


def irregular_plane(spacing: float, half: float, seed: int = 0):
    """A jittered grid (each point moved up to 0.35 spacing), Delaunay-triangulated: cells of
    unequal size and shape, as in scanned meshes."""
    rng = np.random.default_rng(seed)
    g = np.arange(-half, half + 1e-9, spacing)
    xy = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    xy = xy + rng.uniform(-0.35, 0.35, size=xy.shape) * spacing
    faces = Delaunay(xy).simplices
    return np.column_stack([xy, np.zeros(len(xy))]), faces


def test_irregular_cells_tile_the_plane():
    # Points ~1.5 z_r apart.
    x, faces = irregular_plane(1.0, 9.0)
    field = NearField.build(x, faces, np.tile([0.0, 0.0, 1.0], (len(x), 1)), P)
    inner = np.flatnonzero(np.linalg.norm(x[:, :2], axis=1) < 2.0)
    for o in inner[:20]:
        sources = np.flatnonzero(np.linalg.norm(x - x[o], axis=1) < 6.0)
        got = field.weights(np.full(len(sources), o), sources).sum(axis=0)
        # Everything the mesh covers within reach: the disc integral to 6 mm less its missing rim.
        np.testing.assert_allclose(got, disc_integral(6.0, P), rtol=0.02)


def test_far_sources_are_discs():
    x, faces = irregular_plane(1.0, 9.0)
    field = NearField.build(x, faces, np.tile([0.0, 0.0, 1.0], (len(x), 1)), LOW)
    centre = int(np.argmin(np.linalg.norm(x, axis=1)))
    far = np.flatnonzero(np.linalg.norm(x - x[centre], axis=1) > 5.0)[:50]
    got = field.weights(np.full(len(far), centre), far)
    radius = np.sqrt(field.area[far] / np.pi)
    expected = disc_mean_exact(np.linalg.norm(x[far] - x[centre], axis=1), radius, LOW) * field.area[far, None]
    np.testing.assert_allclose(got, expected, rtol=3e-3)


def numpy_weights(field: NearField, o: np.ndarray, i: np.ndarray) -> np.ndarray:
    """`NearField.weights` as numpy formulated it before it was compiled: point values far
    from small sources, the own cell, sub-triangles within ZONE (exact where they share the
    receiver's triangle), else a disc in the source's plane (`DiscMean`)."""
    x = field.positions
    delta = x[o] - x[i]
    d = np.linalg.norm(delta, axis=1)
    radius = np.sqrt(field.area / np.pi)
    out = np.empty((len(o), 3))
    for k in range(len(o)):
        a, b = o[k], i[k]
        if a != b and is_point(field.disc, d[k:k + 1], radius[b:b + 1])[0]:
            out[k] = diffuse_reflectance_profile(d[k], field.disc.params) * field.area[b]
        elif a == b:
            out[k] = field.own[a]
        elif d[k] < ZONE * (radius[a] + radius[b]):
            out[k] = 0.0
            for s in range(field.sub_ptr[b], field.sub_ptr[b + 1]):
                tri = field.sub_corners[s]
                if a in field.sub_face[s]:
                    out[k] += triangle_integral_in_plane(x[a][None], tri[:1], tri[1:2], tri[2:], field.cumulative)[0]
                else:
                    ds = x[a] - tri.mean(axis=0)
                    h = abs(ds @ field.sub_normal[s])
                    out[k] += disc_mean(field.disc, np.array([np.linalg.norm(ds)]), np.array([np.sqrt(field.sub_area[s] / np.pi)]),
                                         np.array([h]))[0] * field.sub_area[s]
        else:
            h = abs(delta[k] @ field.normals[b])
            out[k] = disc_mean(field.disc, d[k:k + 1], radius[b:b + 1], np.array([h]))[0] * field.area[b]
    return out


@pytest.mark.parametrize("material", ["marble", "ketchup", "skin2"])
def test_compiled_weights_equal_the_numpy_formulation(material):
    # A folded, irregular surface (sources off each other's planes: the tilted and polar disc
    # cases too): the compiled pair weights equal the numpy definition within float32 rounding
    # (the radial table's interpolation, ~1e-7).
    x, faces = irregular_plane(1.0, 5.0, seed=1)
    x[:, 2] = 1.5 * np.sin(x[:, 0]) * np.cos(0.7 * x[:, 1])
    normals = area_weighted_normals(x, faces)
    field = NearField.build(x, faces, normals, profile_for(preset(material)))
    centre = np.flatnonzero(np.linalg.norm(x[:, :2], axis=1) < 2.5)
    o = np.repeat(centre, len(x))
    i = np.tile(np.arange(len(x)), len(centre))
    got, expected = field.weights(o, i), numpy_weights(field, o, i)
    np.testing.assert_allclose(got, expected, rtol=3e-7, atol=1e-7 * np.abs(expected).max())


@pytest.mark.parametrize("material", ["marble", "ketchup", "skin1", "spectralon"])
def test_radial_table_equals_the_disc_expansion(material):
    # `_radial` reads Rd and the expansion's spread terms from a table in ln r; within its range
    # it equals the numpy expansion to ~1e-7 of Rd, beyond it the compiled exact sum.
    p = profile_for(preset(material))
    x, faces = irregular_plane(1.0, 2.0)
    field = NearField.build(x * 30.0, faces, np.tile([0.0, 0.0, 1.0], (len(x), 1)), p)  # ~170 mm across
    radial = field.kernel_args[4][9]
    rng = np.random.default_rng(2)
    r = np.exp(rng.uniform(np.log(1e-3 * p.z_min.min()), np.log(60.0), 3000))
    a, h = r * rng.uniform(0.0, 0.3, len(r)), r * rng.uniform(0.0, 1.0, len(r))
    got = np.empty((len(r), 3))
    for k in range(len(r)):
        scatter_kernels._radial(r[k], a[k], h[k], radial, p.weight, p.depth, p.sigma, got[k])
    expected = disc_expansion(r, a, h, p)
    point = diffuse_reflectance_profile(r, p)
    assert np.all(np.abs(got - expected) <= 3e-7 * point + 1e-300)


def test_compiled_exact_disc_mean_equals_numpy():
    # The exact disc mean the compiled disc falls back to (edges, tilted discs near their plane)
    # and tabulates, inside (d < a) and outside the disc, in and above its plane.
    p = profile_for(preset("skin2"))
    x, w = np.polynomial.legendre.leggauss(64)
    rng = np.random.default_rng(3)
    d, a = rng.uniform(0.0, 3.0, 40), rng.uniform(0.05, 1.0, 40)
    h = np.where(np.arange(40) % 2, rng.uniform(0.0, 0.5, 40), 0.0)
    got = np.empty((40, 3))
    for k in range(40):
        scatter_kernels.disc_mean_exact_one(d[k], a[k], h[k], p.weight, p.depth, p.sigma, x, w, got[k])
    np.testing.assert_allclose(got, disc_mean_exact(d, a, p, h), rtol=1e-12)
