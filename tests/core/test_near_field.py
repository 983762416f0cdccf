"""Weights of source cells at a receiver: on an irregular plane they tile, so their sum is the
integral of Rd over the plane; far sources fall back to the disc mean."""

import numpy as np
from scipy.spatial import Delaunay

from sssbake.pipeline.core.profile import classical_dipole, disc_integral
from sssbake.pipeline.core.disc_average import disc_mean_exact
from sssbake.pipeline.core.near_field import NearField

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
