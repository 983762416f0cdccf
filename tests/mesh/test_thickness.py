import numpy as np
import pytest
import trimesh

from sssbake.pipeline.mesh.thickness import ThicknessError, bake_thickness

R = 2.0


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(3, radius=R)


@pytest.fixture(scope="module")
def slab():
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.05))
    positions, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.1)
    return trimesh.Trimesh(positions, faces)


def test_sphere_is_two_radii_thick_at_every_vertex(sphere):
    result = bake_thickness(sphere.vertices, sphere.faces, sphere.vertex_normals, cap=10.0)
    assert result.hit.all() and (result.hit_fraction == 1.0).all()
    np.testing.assert_allclose(result.thickness, 2 * R, rtol=0.01)


def test_slab_is_t_thick_on_its_big_faces(slab):
    result = bake_thickness(slab.vertices, slab.faces, slab.vertex_normals, cap=10.0)
    big = np.abs(slab.vertex_normals[:, 2]) > 0.9999
    assert big.sum() > 100
    np.testing.assert_allclose(result.thickness[big], 0.05, rtol=0.01)


def test_samples_with_their_own_directions(sphere):
    # From a face centroid along the inward face normal the chord of this centrally symmetric
    # polytope ends on the parallel opposite face: twice the face's distance from the centre.
    centroids = sphere.triangles_center
    normals = sphere.face_normals
    result = bake_thickness(sphere.vertices, sphere.faces, origins=centroids, directions=-3.0 * normals, cap=10.0)
    expected = 2.0 * np.einsum("ij,ij->i", centroids, normals)
    np.testing.assert_allclose(result.thickness, expected, rtol=1e-5)


def test_open_shell_rays_escape_to_the_cap():
    ball = trimesh.creation.icosphere(3)
    upper = ball.triangles_center[:, 2] > 0.0
    shell = trimesh.Trimesh(ball.vertices, ball.faces[upper])
    shell.remove_unreferenced_vertices()
    result = bake_thickness(shell.vertices, shell.faces, shell.vertex_normals, cap=0.7)
    away_from_rim = shell.vertices[:, 2] > 0.1
    assert not result.hit[away_from_rim].any()
    np.testing.assert_array_equal(result.thickness[away_from_rim], 0.7)
    assert np.isfinite(result.thickness).all() and (result.thickness <= 0.7).all()


def test_thickness_is_capped_but_still_a_hit(sphere):
    result = bake_thickness(sphere.vertices, sphere.faces, sphere.vertex_normals, cap=1.5)
    assert result.hit.all()
    np.testing.assert_array_equal(result.thickness, 1.5)


def test_cone_of_rays_is_close_and_biased_as_documented(sphere, slab):
    thick = bake_thickness(sphere.vertices, sphere.faces, sphere.vertex_normals, cap=10.0, rays=5)
    assert np.isfinite(thick.thickness).all() and thick.hit.all()
    assert -0.03 < thick.thickness.mean() / (2 * R) - 1 < 0.0
    flat = bake_thickness(slab.vertices, slab.faces, slab.vertex_normals, cap=10.0, rays=5)
    big = np.abs(slab.vertex_normals[:, 2]) > 0.9999
    assert 0.0 < flat.thickness[big].mean() / 0.05 - 1 < 0.03


def test_bad_input_raises(sphere):
    with pytest.raises(ThicknessError, match="cap"):
        bake_thickness(sphere.vertices, sphere.faces, sphere.vertex_normals, cap=0.0)
    with pytest.raises(ThicknessError, match="origins need directions"):
        bake_thickness(sphere.vertices, sphere.faces, origins=sphere.vertices, cap=1.0)
    with pytest.raises(ValueError, match="zero-length"):
        bake_thickness(sphere.vertices, sphere.faces, sphere.vertex_normals * 0.0, cap=1.0)
