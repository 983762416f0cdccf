"""Vertex tangents: glTF handedness, orthonormal frames, degenerate UVs, and their place in cleaning."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.scene import Mesh, Node, Primitive, Scene, SourceMaterial, TextureRef
from sssbake.pipeline.mesh.tangents import vertex_tangents

HELMET = Path("/work/shared/assets/damaged_helmet/DamagedHelmet.glb")


def grid(k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """(k², 3) vertices of the unit square in z = 0 and its (2 (k-1)², 3) counter-clockwise faces."""
    g = np.linspace(0.0, 1.0, k)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    v = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(k * k)])
    idx = np.arange(k * k).reshape(k, k)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def uv_sphere(rows: int = 24, cols: int = 48) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit sphere (Y up) with an equirectangular map seen unmirrored from outside.

    Returns (n, 3) positions (= normals), (m, 3) counter-clockwise faces, (n, 2) glTF UVs: u grows
    with longitude, v from 0 at the north pole to 1 at the south pole; seam and pole vertices are
    duplicated per column, pole caps are single triangles.
    """
    theta, phi = np.meshgrid(np.linspace(0, np.pi, rows + 1), np.linspace(0, 2 * np.pi, cols + 1), indexing="ij")
    v = np.column_stack([(np.sin(theta) * np.cos(phi)).ravel(), np.cos(theta).ravel(),
                         (-np.sin(theta) * np.sin(phi)).ravel()])
    uv = np.column_stack([phi.ravel() / (2 * np.pi), theta.ravel() / np.pi])
    idx = np.arange(v.shape[0]).reshape(rows + 1, cols + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    lower = np.stack([a, b, c], axis=-1)[:-1].reshape(-1, 3)  # the last row's would join two south poles
    upper = np.stack([a, c, d], axis=-1)[1:].reshape(-1, 3)  # the first row's would join two north poles
    return v, np.concatenate([lower, upper]), uv


def test_flat_grid_gives_the_u_axis_with_gltf_handedness():
    v, f = grid()
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    # The image upright seen from +z: u right along +x, glTF v down the image, i.e. along -y.
    t = vertex_tangents(v, f, n, np.column_stack([3.0 * v[:, 0], 1.0 - 2.0 * v[:, 1]]))
    np.testing.assert_allclose(t, np.tile([1.0, 0.0, 0.0, 1.0], (len(v), 1)), atol=1e-12)
    # glTF: bitangent = cross(normal, tangent) * w points up the image (+y here).
    np.testing.assert_allclose(np.cross(n, t[:, :3]) * t[:, 3:], np.tile([0.0, 1.0, 0.0], (len(v), 1)), atol=1e-12)
    # The image flipped vertically is a mirrored layout: same tangent, w = -1.
    mirrored = vertex_tangents(v, f, n, v[:, :2])
    np.testing.assert_allclose(mirrored, np.tile([1.0, 0.0, 0.0, -1.0], (len(v), 1)), atol=1e-12)


def test_tangents_turn_with_the_mesh():
    v, f = grid()
    uv = np.column_stack([v[:, 0], 1.0 - v[:, 1]])
    rot = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    n = np.tile(rot[:, 2], (len(v), 1))
    t = vertex_tangents(v @ rot.T, f, n, uv)
    np.testing.assert_allclose(t[:, :3], np.tile(rot[:, 0], (len(v), 1)), atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], 1.0)


def test_sphere_tangents_are_unit_orthogonal_and_follow_longitude():
    v, f, uv = uv_sphere()
    centroids = v[f].mean(axis=1)
    face_normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert (np.einsum("ij,ij->i", face_normals, centroids) > 0).all()
    t = vertex_tangents(v, f, v, uv)
    assert np.isfinite(t).all()
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", t[:, :3], v), 0.0, atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], 1.0)
    # Away from the poles: the direction of growing longitude (dP/dphi, normalised); exact where
    # faces on both sides cancel each other's chord error, within half a column on the UV seam.
    phi = uv[:, 0] * 2 * np.pi
    expected = np.column_stack([-np.sin(phi), np.zeros(len(v)), -np.cos(phi)])
    body = np.abs(v[:, 1]) < 0.9
    seam = (uv[:, 0] == 0.0) | (uv[:, 0] == 1.0)
    np.testing.assert_allclose(t[body & ~seam, :3], expected[body & ~seam], atol=1e-9)
    half_column = np.pi * np.unique(uv[:, 0])[1]
    assert (np.einsum("ij,ij->i", t[body & seam, :3], expected[body & seam]) > np.cos(half_column)).all()


def test_degenerate_uvs_fall_back_to_a_perpendicular_without_nan():
    v, f = grid(3)
    n = np.tile([0.0, 0.6, 0.8], (len(v), 1))
    for uv in (np.zeros((len(v), 2)), np.column_stack([v[:, 0], v[:, 0]])):  # collapsed; collinear
        t = vertex_tangents(v, f, n, uv)
        assert np.isfinite(t).all()
        np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(np.einsum("ij,ij->i", t[:, :3], n), 0.0, atol=1e-12)
        np.testing.assert_array_equal(t[:, 3], 1.0)


def test_one_degenerate_face_leaves_its_neighbours_alone():
    v, f = grid(3)
    v = np.vstack([v, [[5.0, 5.0, 0.0]]])  # referenced by no face
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    uv = np.column_stack([v[:, 0], 1.0 - v[:, 1]])
    uv[f[0]] = uv[f[0, 0]]  # the first face's UVs collapse to one point; its neighbours' get skewed
    t = vertex_tangents(v, f, n, uv)
    assert np.isfinite(t).all()
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(t[:, 2], 0.0, atol=1e-12)
    untouched = np.setdiff1d(np.arange(9), f[np.any(np.isin(f, f[0]), axis=1)])
    assert len(untouched)
    np.testing.assert_allclose(t[untouched], np.tile([1.0, 0.0, 0.0, 1.0], (len(untouched), 1)), atol=1e-12)


def _scene(prim: Primitive, *materials: SourceMaterial) -> Scene:
    return Scene("t.glb", (Mesh("m", (prim,)),), (Node("n", np.eye(4), 0),), (0,), materials=materials)


def test_clean_generates_tangents_from_the_normal_textures_uv_set():
    v, f = grid()
    upright = np.column_stack([v[:, 0], 1.0 - v[:, 1]])
    swapped = upright[:, ::-1].copy()  # would give +y tangents
    bumpy = SourceMaterial("bumpy", normal_texture=TextureRef(0, tex_coord=1))
    out = clean_scene(_scene(Primitive(v, f, uvs=(swapped, upright), material=0), bumpy))
    prim = out.scene.meshes[0].primitives[0]
    np.testing.assert_allclose(prim.tangents, np.tile([1.0, 0.0, 0.0, 1.0], (len(v), 1)), atol=1e-12)
    assert not out.warnings

    out = clean_scene(_scene(Primitive(v, f, uvs=(upright,), material=0), bumpy))
    assert out.scene.meshes[0].primitives[0].tangents is None
    assert any("TEXCOORD_1" in w for w in out.warnings)

    plain = SourceMaterial("plain")
    for prim in (Primitive(v, f, uvs=(upright,), material=0), Primitive(v, f, uvs=(upright,))):
        assert clean_scene(_scene(prim, plain)).scene.meshes[0].primitives[0].tangents is None


def test_clean_keeps_given_tangents_through_the_remap_and_drops_unusable_ones():
    v, f = grid()
    v = np.vstack([[9.0, 9.0, 9.0], v])  # an unused vertex in front shifts every index
    f = f + 1
    given = np.column_stack([np.tile([0.0, 1.0, 0.0], (len(v), 1)), np.where(np.arange(len(v)) % 2, 1.0, -1.0)])
    out = clean_scene(_scene(Primitive(v, f, tangents=given)))
    np.testing.assert_array_equal(out.scene.meshes[0].primitives[0].tangents, given[1:])

    for row, bad in ((3, [np.nan, 1.0, 0.0, 1.0]), (4, [0.0, 0.0, 0.0, 1.0])):
        broken = given.copy()
        broken[row] = bad
        assert clean_scene(_scene(Primitive(v, f, tangents=broken))).scene.meshes[0].primitives[0].tangents is None
    given[3, 0] = np.nan
    # Dropped tangents are made anew when the material needs them.
    bumpy = SourceMaterial("bumpy", normal_texture=TextureRef(0))
    uv = np.column_stack([v[:, 0], 1.0 - v[:, 1]])
    out = clean_scene(_scene(Primitive(v, f, uvs=(uv,), material=0, tangents=given), bumpy))
    prim = out.scene.meshes[0].primitives[0]
    np.testing.assert_allclose(prim.tangents, np.tile([1.0, 0.0, 0.0, 1.0], (len(v) - 1, 1)), atol=1e-12)


@pytest.mark.skipif(not HELMET.is_file(), reason=f"{HELMET} is absent")
def test_damaged_helmet_exports_without_validator_warnings(tmp_path):
    from sssbake.exporters.gltf import write_glb
    from sssbake.exporters.gltf_validator import validate_glb
    from sssbake.pipeline.mesh.baked import BakedAsset
    from sssbake.pipeline.mesh.load import load_scene

    cleaned = clean_scene(load_scene(str(HELMET)))
    assert all(p.tangents is not None for m in cleaned.scene.meshes for p in m.primitives)
    write_glb(BakedAsset(cleaned.scene), tmp_path / "helmet.glb")
    report = validate_glb(tmp_path / "helmet.glb")
    assert (report.num_errors, report.num_warnings) == (0, 0), report.codes()
