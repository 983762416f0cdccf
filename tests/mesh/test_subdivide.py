"""Midpoint subdivision of a welded surface: the same surface, four times the triangles."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.mesh.subdivide import subdivided_surface


def test_subdivision_keeps_the_surface_and_interpolates_normals():
    ball = trimesh.creation.icosphere(subdivisions=1)
    surface = weld_surface([Primitive(positions=ball.vertices, faces=ball.faces)], 1e-9)
    assert subdivided_surface(surface, 0) is surface
    fine = subdivided_surface(surface, 2)
    assert len(fine.faces) == 16 * len(surface.faces)
    # a closed mesh: V - E + F = 2 at every level, E = 3F / 2
    assert len(fine.positions) - 3 * len(fine.faces) // 2 + len(fine.faces) == 2
    np.testing.assert_allclose(fine.vertex_areas.sum(), surface.vertex_areas.sum(), rtol=1e-12)
    np.testing.assert_array_equal(fine.positions[: len(surface.positions)], surface.positions)
    np.testing.assert_allclose(np.linalg.norm(fine.normals, axis=1), 1.0, rtol=1e-12)
    # an edge midpoint's normal is the normalised mean of its ends'
    a, b = surface.faces[0, :2]
    mid = np.flatnonzero(np.all(np.isclose(fine.positions, 0.5 * (surface.positions[a] + surface.positions[b])), axis=1))
    expected = surface.normals[a] + surface.normals[b]
    np.testing.assert_allclose(fine.normals[mid[0]], expected / np.linalg.norm(expected), rtol=1e-12)
    assert len(fine.weld) == 1 and np.array_equal(fine.weld[0], np.arange(len(fine.positions)))
    with pytest.raises(ValueError, match="levels"):
        subdivided_surface(surface, -1)
