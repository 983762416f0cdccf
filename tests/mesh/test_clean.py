import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.core.surface import area_weighted_normals, vertex_areas
from sssbake.pipeline.mesh.clean import clean_scene, weld_positions
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene


def _scene(*prims: Primitive) -> Scene:
    return Scene("t.obj", (Mesh("m", tuple(prims)),), (Node("n", np.eye(4), 0),), (0,))


def test_vertex_areas_sum_to_surface_area():
    s = trimesh.creation.icosphere(subdivisions=3, radius=2.0)
    a = vertex_areas(np.asarray(s.vertices), np.asarray(s.faces))
    np.testing.assert_allclose(a.sum(), s.area, rtol=1e-12)
    # A regular grid's interior vertex owns exactly one cell: 6 triangles / 3 = one square of side h.
    h = 0.1
    g = np.arange(3) * h
    xx, yy = np.meshgrid(g, g, indexing="ij")
    v = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(9)])
    idx = np.arange(9).reshape(3, 3)
    a0, b0, c0, d0 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.column_stack([a0, b0, c0]), np.column_stack([a0, c0, d0])])
    np.testing.assert_allclose(vertex_areas(v, f)[4], h * h)


def test_normals_of_a_sphere_point_outward():
    s = trimesh.creation.icosphere(subdivisions=3)
    n = area_weighted_normals(np.asarray(s.vertices), np.asarray(s.faces))
    np.testing.assert_allclose(np.einsum("ij,ij->i", n, s.vertices), 1.0, atol=5e-3)


def test_weld_joins_seams_only_within_tolerance():
    p = np.array([[0, 0, 0], [1e-9, 0, 0], [1, 0, 0], [1 + 1e-3, 0, 0]], dtype=float)
    welded, idx = weld_positions(p, 1e-7)
    assert len(welded) == 3 and idx[0] == idx[1] and idx[2] != idx[3]


def test_clean_drops_degenerates_and_unused_and_fills_normals():
    s = trimesh.creation.icosphere(subdivisions=2)
    v = np.vstack([s.vertices, [[5.0, 5.0, 5.0]]])  # an unused vertex
    f = np.vstack([s.faces, [[0, 0, 1]], [[0, 1, 1]]])  # two degenerate triangles
    uv = np.column_stack([np.arange(len(v)) / len(v), np.zeros(len(v))])
    out = clean_scene(_scene(Primitive(v, f, uvs=(uv,))))
    prim = out.scene.meshes[0].primitives[0]
    assert len(prim.faces) == len(s.faces) and len(prim.positions) == len(s.vertices)
    np.testing.assert_array_equal(prim.uvs[0], uv[: len(s.vertices)])
    assert prim.normals is not None and np.allclose(np.linalg.norm(prim.normals, axis=1), 1.0)
    assert any("2 degenerate" in w for w in out.warnings)
    np.testing.assert_allclose(out.surfaces[0].area, s.area, rtol=1e-12)


def test_surface_welds_across_primitives_and_seams():
    # A sphere split into two primitives with duplicated seam vertices must weld into one surface.
    s = trimesh.creation.icosphere(subdivisions=2)
    half = len(s.faces) // 2
    parts = []
    for faces in (s.faces[:half], s.faces[half:]):
        used, inv = np.unique(faces, return_inverse=True)
        parts.append(Primitive(np.asarray(s.vertices)[used], inv.reshape(-1, 3).astype(np.int64)))
    out = clean_scene(_scene(*parts))
    surf = out.surfaces[0]
    assert len(surf.positions) == len(s.vertices)
    for prim, w in zip(out.scene.meshes[0].primitives, surf.weld):
        np.testing.assert_allclose(surf.positions[w], prim.positions)
    edges = trimesh.Trimesh(surf.positions, surf.faces, process=False)
    assert edges.is_watertight


def test_mesh_without_area_is_left_out_and_all_degenerate_raises():
    good = Primitive(np.eye(3), np.array([[0, 1, 2]]))
    flat = Primitive(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    sc = Scene("t.glb", (Mesh("flat", (flat,)), Mesh("good", (good,))),
               (Node("a", np.eye(4), 0), Node("b", np.eye(4), 1)), (0, 1))
    out = clean_scene(sc)
    assert [m.name for m in out.scene.meshes] == ["good"]
    assert out.scene.nodes[0].mesh is None and out.scene.nodes[1].mesh == 0
    with pytest.raises(AssetError, match="non-zero area"):
        clean_scene(_scene(flat))


def test_inward_winding_is_flipped_outward():
    s = trimesh.creation.icosphere(subdivisions=2)
    inward = Primitive(np.asarray(s.vertices), np.asarray(s.faces)[:, ::-1].copy())
    out = clean_scene(_scene(inward))
    prim = out.scene.meshes[0].primitives[0]
    np.testing.assert_array_equal(prim.faces, s.faces)
    assert np.einsum("ij,ij->i", prim.normals, s.vertices).min() > 0.9
    assert any("wound inward" in w for w in out.warnings)
    # An open, flat patch encloses nothing and is never flipped.
    flat = Primitive(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), np.array([[0, 2, 1]]))
    assert clean_scene(_scene(flat)).scene.meshes[0].primitives[0].faces.tolist() == [[0, 2, 1]]


@pytest.mark.parametrize("length", [1e300, 1e200, 1.0, 1e-6])
def test_authored_normals_of_any_finite_length_keep_their_direction_silently(length):
    import warnings

    s = trimesh.creation.icosphere(subdivisions=2)
    directions = np.asarray(s.vertices) + [0.1, -0.2, 0.05]  # not the computed normals, so they must be the authored ones
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflowing length would warn and give zero normals
        out = clean_scene(_scene(Primitive(np.asarray(s.vertices), np.asarray(s.faces), normals=directions * length)))
    np.testing.assert_allclose(out.scene.meshes[0].primitives[0].normals, directions, rtol=1e-12, atol=1e-15)


def test_repeated_triangles_go_and_back_faces_stay():
    s = trimesh.creation.icosphere(subdivisions=2)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    # the first face again three times, once turned (same order from another corner), once as a
    # seam copy (its own vertices, welded to the same corners), and one face reversed (a back face)
    copies = np.vstack([v, v[f[0]]])
    seam = np.arange(len(v), len(v) + 3)
    faces = np.vstack([f, f[:1], f[:1, [1, 2, 0]], seam[None], f[1:2, ::-1]])
    out = clean_scene(_scene(Primitive(copies, faces)))
    kept = out.scene.meshes[0].primitives[0].faces
    assert len(kept) == len(f) + 1
    assert any("dropped 3 repeated triangles" in w for w in out.warnings)
    np.testing.assert_allclose(out.surfaces[0].area, s.area + _area(v, f[1]), rtol=1e-12)  # the back face counts once


def _area(v, face):
    a, b, c = v[face]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a))
