"""Generalized winding numbers and edge defects: closed forms on a cube and an open hemisphere."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.mesh.winding import EdgeDefects, edge_defects, inside, winding_numbers


@pytest.fixture(scope="module")
def cube():
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    return np.asarray(box.vertices, dtype=np.float64), np.asarray(box.faces, dtype=np.int64)


def test_closed_cube_counts_one_inside_zero_outside(cube):
    v, f = cube
    w = winding_numbers(v, f, [[0.0, 0.0, 0.0], [0.9, -0.9, 0.5], [1.5, 0.0, 0.0], [0.0, 0.0, -3.0]])
    # far triangles are a Taylor expansion (Barill et al. 2018): ~1e-4 off at a cube's size
    np.testing.assert_allclose(w, [1.0, 1.0, 0.0, 0.0], atol=1e-3)
    # an inward-wound shell counts -1: still inside by |w| > 1/2 (the non-zero rule)
    assert inside(winding_numbers(v, f[:, ::-1], [[0.0, 0.0, 0.0]])).all()
    assert winding_numbers(v, f, np.zeros((0, 3))).shape == (0,)


def test_over_a_planar_opening_the_inside_ends_on_its_plane(cube):
    # without its top face (z = 1) the cube's w on that plane is 1/2: the opening's solid angle is
    # 2π from every point of it, so w is 1 - 1/2 just below and 0 + 1/2 just above
    v, f = cube
    top = np.all(v[f][:, :, 2] == 1.0, axis=1)
    points = [[0.3, -0.2, 1.0 - 1e-3], [0.3, -0.2, 1.0 + 1e-3], [0.0, 0.0, 0.0]]
    w = winding_numbers(v, f[~top], points)
    assert w[0] > 0.5 > w[1] and w[2] > 0.7
    np.testing.assert_allclose(w[:2], 0.5, atol=2e-3)


def test_edge_defects_name_openings_non_manifold_edges_and_folds(cube):
    _, f = cube
    assert edge_defects(f) == EdgeDefects(0, 0, 0) and edge_defects(f).closed
    assert edge_defects(f).describe() == "closed"
    opened = edge_defects(f[1:])  # one triangle missing: its three edges have one triangle each
    assert opened == EdgeDefects(3, 0, 0) and not opened.closed
    assert opened.describe() == "3 edges on openings"
    folded = f.copy()
    folded[0] = folded[0, ::-1]  # wound against its three neighbours: closed, but folded
    assert edge_defects(folded) == EdgeDefects(0, 0, 3)
    assert "3 folded edges" in edge_defects(folded).describe()
    fin = np.vstack([f, [[f[0, 0], f[0, 1], 8]]])  # a third triangle on an edge of the cube
    assert edge_defects(fin).nonmanifold == 1 and edge_defects(fin).boundary == 2
