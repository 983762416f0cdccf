"""Locating points on a simplified copy of a surface: the closest triangle, against brute force."""

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point

from sssbake.pipeline.mesh.surface_locate import _triangle_distance2, locate_on_mesh


def test_triangle_distance_matches_the_closest_point_of_every_region_and_degenerate_triangles():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(4000, 3, 3))
    tri[:500, 1] = tri[:500, 0]  # a and b coincide: the segment ac
    tri[500:700, 2] = tri[500:700, 0] + 0.3 * (tri[500:700, 1] - tri[500:700, 0])  # collinear corners
    tri[700:800] = tri[700:800, :1]  # a point
    p = rng.normal(size=(4000, 3)) * 2.0  # all seven Voronoi regions of a triangle
    expected = np.sum((closest_point(tri, p) - p) ** 2, axis=1)
    np.testing.assert_allclose(_triangle_distance2(p, tri), expected, rtol=1e-9, atol=1e-12)


def test_points_near_a_surface_land_on_its_closest_triangle():
    coarse = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(1)
    direction = rng.normal(size=(3000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = direction * rng.uniform(0.97, 1.03, (3000, 1))  # a finer surface's points, off the coarse one
    face, bary = locate_on_mesh(points, coarse.vertices, coarse.faces)
    assert np.all(bary >= 0) and np.allclose(bary.sum(axis=1), 1.0)
    located = np.einsum("pk,pkd->pd", bary, coarse.vertices[coarse.faces[face]])
    # brute force: every triangle for every point
    tris = coarse.vertices[coarse.faces]
    best = np.array([np.min(np.sum((closest_point(tris, np.broadcast_to(q, (len(tris), 3))) - q) ** 2, axis=1))
                     for q in points])
    np.testing.assert_allclose(np.sum((located - points) ** 2, axis=1), best, rtol=1e-9, atol=1e-15)


def test_ties_land_on_the_same_point_as_testing_every_candidate():
    # Points above the vertices and edge midpoints of a convex mesh are closest to a corner or an
    # edge that several candidate triangles share. Against the slow path (trimesh's closest point
    # of every candidate, the first nearest): the same face but where the distances tie to
    # rounding, and the same located point.
    mesh = trimesh.creation.icosphere(subdivisions=2)
    x, f = mesh.vertices, mesh.faces
    edges = mesh.edges_unique
    points = np.r_[x * 1.02, 0.5 * (x[edges[:, 0]] + x[edges[:, 1]]) * 1.03, x * 0.99]
    face, bary = locate_on_mesh(points, x, f)
    _, near = cKDTree(x).query(points, k=4)
    expected_face = np.empty(len(points), dtype=np.int64)
    expected_point = np.empty((len(points), 3))
    chosen_distance, best_distance = np.empty(len(points)), np.empty(len(points))
    for i, p in enumerate(points):
        candidates = np.unique(np.flatnonzero(np.isin(f, near[i]).any(axis=1)))
        closest = closest_point(x[f[candidates]], np.broadcast_to(p, (len(candidates), 3)))
        distance = np.sum((closest - p) ** 2, axis=1)
        pick = int(np.argmin(distance))
        expected_face[i], expected_point[i], best_distance[i] = candidates[pick], closest[pick], distance[pick]
        chosen_distance[i] = distance[np.flatnonzero(candidates == face[i])[0]]
    differ = face != expected_face
    assert differ.sum() < 0.02 * len(points)
    np.testing.assert_allclose(chosen_distance[differ], best_distance[differ], rtol=1e-12)
    located = np.einsum("pk,pkd->pd", bary, x[f[face]])
    np.testing.assert_allclose(located, expected_point, atol=1e-12)


def test_a_point_on_a_triangle_without_area_takes_its_nearest_corner():
    # a flat fan around the origin plus a collapsed triangle (all three corners on one line) above it
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, -1, 0], [0, 0, 1], [0.5, 0, 1], [1, 0, 1.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    face, bary = locate_on_mesh(np.array([[0.55, 0.0, 1.0]]), positions, faces)
    assert face[0] == 2 and np.isfinite(bary).all()
    np.testing.assert_array_equal(bary[0], [0.0, 1.0, 0.0])  # corner 5, at 0.5 from the point's 0.55
