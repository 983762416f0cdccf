import numpy as np
import pytest
import trimesh
from fixtures import auto_smooth, cylinder, hemisphere
from scipy.spatial.transform import Rotation

from sssbake.pipeline.core.surface import area_weighted_normals
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.mesh.thickness import ThicknessError, bake_thickness, miss_warnings

R = 2.0


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(3, radius=R)


@pytest.fixture(scope="module")
def slab():
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.05))
    positions, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.1)
    return trimesh.Trimesh(positions, faces)


def vertex_thickness(positions, faces, **kwargs):
    """`bake_thickness` of every vertex along its area-weighted normal (the welded surface's), cap 100."""
    positions, faces = np.asarray(positions, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    return bake_thickness(positions, faces, area_weighted_normals(positions, faces), cap=100.0, **kwargs)


def exported_thickness(positions, faces):
    """`bake_thickness` of `positions`, `faces` exported with auto-smoothed normals (split across edges
    sharper than 30°) and welded as the bake does, as (thickness per vertex of `positions`, result)."""
    render_positions, render_faces, normals = auto_smooth(positions, faces)
    surface = weld_surface([Primitive(render_positions, render_faces, normals=normals)], 1e-9)
    assert len(surface.positions) == len(positions)
    result = bake_thickness(surface.positions, surface.faces, surface.normals, split_normals=(surface.weld[0], normals),
                            cap=1000.0)
    # the welded vertex of each of `positions`: the one its first render copy went to
    first = np.full(len(positions), -1)
    first[np.asarray(faces).reshape(-1)[::-1]] = surface.weld[0][::-1]
    return result.thickness[first], result


def test_sphere_is_two_radii_thick_at_every_vertex(sphere):
    result = bake_thickness(sphere.vertices, sphere.faces, sphere.vertex_normals, cap=10.0)
    assert result.hit.all() and (result.hit_fraction == 1.0).all()
    assert result.rays == len(sphere.vertices)  # smooth everywhere: one ray per vertex
    assert result.opening == result.flipped == result.no_inside == 0
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


@pytest.mark.parametrize("size", [10.0, 200.0])
def test_every_vertex_of_a_cube_with_hard_edges_reads_its_edge(size):
    # the 8 corners alone, and with vertices on every edge and face: a corner's averaged normal
    # would read up to the body diagonal, 173 mm; its faces' normals read 100 mm
    box = trimesh.creation.box(extents=(100.0, 100.0, 100.0))
    positions, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, size)
    thickness, result = exported_thickness(positions, faces)
    assert result.hit.all()
    np.testing.assert_allclose(thickness, 100.0, rtol=1e-12)


def test_a_textured_cube_split_at_its_edges_reads_its_edge():
    # render vertices split at every edge (each triangle its own three, normals split), welded to 8
    # as the bake does: the welded normals average three faces with two, one and one triangle each,
    # which read 122-150 mm
    box = trimesh.creation.box(extents=(100.0, 100.0, 100.0))
    corners = np.asarray(box.vertices)[np.asarray(box.faces)].reshape(-1, 3)
    normals = np.repeat(np.asarray(box.face_normals), 3, axis=0)
    prim = Primitive(corners, np.arange(len(corners)).reshape(-1, 3), normals=normals)
    surface = weld_surface([prim], 1e-9)
    assert len(surface.positions) == 8
    result = bake_thickness(surface.positions, surface.faces, surface.normals, split_normals=(surface.weld[0], normals),
                            cap=1000.0)
    assert result.rays == 24  # three faces' normals at each corner
    np.testing.assert_allclose(result.thickness[surface.weld[0]], 100.0, rtol=1e-12)
    # without split normals the corners keep their averaged normals (smooth shading is the author's)
    unsplit = bake_thickness(surface.positions, surface.faces, surface.normals, cap=1000.0)
    assert unsplit.rays == 8 and unsplit.thickness.min() > 120.0


def test_a_thin_slab_reads_its_small_side_at_every_corner_and_edge():
    slab = trimesh.creation.box(extents=(1.0, 2.0, 0.05))
    np.testing.assert_allclose(exported_thickness(slab.vertices, slab.faces)[0], 0.05, rtol=1e-9)
    # tessellated: vertices inside a face read the chord along its normal (the small side on the big
    # faces, the long sides on the narrow ones), those on its edges and corners the small side
    positions, faces = trimesh.remesh.subdivide_to_size(slab.vertices, slab.faces, 0.1)
    thickness, _ = exported_thickness(positions, faces)
    on_x, on_y, on_z = (np.isclose(np.abs(positions[:, a]), h) for a, h in enumerate((0.5, 1.0, 0.025)))
    expected = np.select([on_z, on_x & ~on_y, on_y & ~on_x], [0.05, 1.0, 2.0], default=0.05)
    assert (on_x & ~on_z).sum() > 10 and (on_y & ~on_z).sum() > 10
    np.testing.assert_allclose(thickness, expected, rtol=1e-9)


@pytest.mark.parametrize("height", [3.0, 0.5])
def test_a_capped_cylinder_reads_its_diameter_its_height_and_the_rim_the_shorter(height):
    # its 32 sides 11.25° apart are smooth, its rims split (90°)
    radius = 1.0
    positions, faces = cylinder(radius, height)
    thickness, _ = exported_thickness(positions, faces)
    z, rho = positions[:, 2], np.hypot(positions[:, 0], positions[:, 1])
    side = (np.abs(z) < 0.5 * height - 1e-9) & (rho > 0.5)
    rim = np.isclose(np.abs(z), 0.5 * height) & (rho > 0.5)
    centre = rho < 0.5
    # a side vertex casts through the axis to the opposite vertex (32 is even): the diameter
    np.testing.assert_allclose(thickness[side], 2.0 * radius, rtol=1e-12)
    np.testing.assert_allclose(thickness[centre], height, rtol=1e-12)
    # a rim vertex casts along its side copy's normal (the diameter) and its cap copy's (the height)
    np.testing.assert_allclose(thickness[rim], min(height, 2.0 * radius), rtol=1e-12)


def test_an_open_hemisphere_reads_the_closed_hemispheres_chords():
    # tilted so that its opening is not a face of the bounding box. A dome vertex's ray leaves the
    # open one through its base; the winding number is 1/2 exactly on the base's plane (its rim is a
    # planar loop), so the ray ends there as on the closed one: at p·a / (-d·a) along the inward
    # direction d, a the base plane's normal
    rotation = Rotation.from_euler("xyz", [30.0, 20.0, 0.0], degrees=True).as_matrix()
    closed_v, closed_f = hemisphere(1.0)
    open_v, open_f = hemisphere(1.0, base=False)
    closed_v, open_v = closed_v @ rotation.T, open_v @ rotation.T
    axis = rotation[:, 2]
    dome = open_v @ axis > 1e-9
    inward = -area_weighted_normals(open_v, open_f)[dome]
    exact = (open_v[dome] @ axis) / -(inward @ axis)
    closed_thickness, closed = exported_thickness(closed_v, closed_f)
    np.testing.assert_allclose(closed_thickness[: len(open_v)][dome], exact, rtol=1e-12)
    opened = vertex_thickness(open_v, open_f)
    assert opened.opening == dome.sum() and not opened.hit[dome].any()
    # the fast winding number is up to ~4e-3 off: the base plane moves by as much over the radius
    error = np.abs(opened.thickness[dome] / exact - 1.0)
    assert error.max() < 0.01 and np.median(error) < 0.002, (error.max(), np.median(error))
    # the rim: the closed one's edge between dome and base is a 90° wedge (split normals), ~0 thick
    # along the base's normal; the open one's rim has the inside (|w| > 1/2) on neither side
    np.testing.assert_allclose(opened.thickness[~dome], 0.0, atol=1e-12)
    assert opened.no_inside == (~dome).sum()
    assert np.all(closed_thickness[: len(open_v)][~dome] < 0.05)
    assert miss_warnings(closed, closed_f) == []
    lines = miss_warnings(opened, open_f)
    assert len(lines) == 2 and all(line.startswith("(48 edges on openings): ") for line in lines)
    assert f"{dome.sum()} of {opened.rays} thickness rays met no surface" in lines[0]
    assert "found no inside on either side" in lines[1]


def test_a_cylinder_without_caps_reads_its_diameter():
    # every side vertex off the rims is smooth and its ray meets the opposite wall: the diameter, as
    # with caps (the winding number is not read along rays that meet the surface). The rims' rays run
    # in the openings' planes, where the inside (|w| > 1/2) is recessed into the tube: they graze the
    # opposite rim (at most the diameter) or end with no inside (0)
    positions, faces = cylinder(1.0, 3.0, caps=False)
    result = vertex_thickness(positions, faces)
    rim = np.isclose(np.abs(positions[:, 2]), 1.5)
    np.testing.assert_allclose(result.thickness[~rim], 2.0, rtol=1e-12)
    assert np.all((result.thickness[rim] >= 0.0) & (result.thickness[rim] <= 2.0 + 1e-12))


def test_a_fold_turns_the_ray_back_into_the_object(sphere):
    # all six triangles around one vertex wound inward: its normal points into the sphere, its ray
    # out of it, meeting nothing (the bounding-box cap before). Ahead of it the winding number is
    # outside, behind it inside: it is cast the other way, through the centre: 2R
    faces = np.array(sphere.faces)
    vertex = 0
    ring = np.any(faces == vertex, axis=1)
    faces[ring] = faces[ring, ::-1]
    result = vertex_thickness(sphere.vertices, faces)
    assert result.flipped == 1 and result.opening == result.no_inside == 0 and result.hit.all()
    assert result.thickness[vertex] == pytest.approx(2 * R, rel=1e-12)
    # the ring around it: its normals are tilted by the two inward triangles each, within 1 %
    np.testing.assert_allclose(result.thickness, 2 * R, rtol=0.01)
    # a fold on a closed surface, not an opening
    assert miss_warnings(result, faces) == [
        f"(5 folded edges (neighbours wound against each other)): 1 of {result.rays} thickness rays started "
        "with the inside behind them (folded triangles); they were cast the other way"]


def test_one_folded_triangle_is_not_an_opening(sphere):
    # wound against its neighbours, it tilts its corners' normals a little; every ray meets the sphere
    faces = np.array(sphere.faces)
    faces[7] = faces[7, ::-1]
    result = vertex_thickness(sphere.vertices, faces)
    assert result.hit.all() and result.flipped == result.opening == result.no_inside == 0
    assert miss_warnings(result, faces) == []
    np.testing.assert_allclose(result.thickness, 2 * R, rtol=0.01)


def test_normals_given_inward_are_turned_back(sphere):
    result = bake_thickness(sphere.vertices, sphere.faces, -np.asarray(sphere.vertex_normals), cap=10.0)
    assert result.flipped == len(sphere.vertices) and result.hit.all()
    np.testing.assert_allclose(result.thickness, 2 * R, rtol=0.01)


def test_a_sheet_has_no_inside_and_no_thickness():
    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    result = vertex_thickness(square, [[0, 1, 2], [0, 2, 3]])
    assert result.no_inside == 4 and not result.hit.any()
    np.testing.assert_array_equal(result.thickness, 0.0)
