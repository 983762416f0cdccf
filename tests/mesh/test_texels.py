import numpy as np
import pytest
import trimesh
import xatlas

from sssbake.pipeline.mesh.atlas import compute_atlas
from sssbake.pipeline.mesh.texels import TexelError, dilate, rasterize_atlas

UP = np.tile([0.0, 0.0, 1.0], (3, 1))


def _flat(uv):
    """A triangle lying in the z = 0 plane at its own UV coordinates."""
    return np.c_[uv, np.zeros(len(uv))]


@pytest.fixture(scope="module")
def sphere_texels():
    mesh = trimesh.creation.icosphere(3)
    atlas = compute_atlas([(mesh.vertices, mesh.faces)], resolution=512, padding=4)
    part = atlas.parts[0]
    texels = rasterize_atlas(
        [(part.uvs, part.faces, mesh.vertices[part.vmapping], mesh.vertex_normals[part.vmapping])],
        atlas.width,
        atlas.height,
    )
    return mesh, part, texels


def test_single_triangle_covers_the_analytic_texel_count():
    # Centres (c + 0.5, r + 0.5) / 10 lie inside u + v <= 0.95 exactly when r + c <= 8: 9·10/2 texels.
    uv = np.array([[0.0, 0.0], [0.95, 0.0], [0.0, 0.95]])
    texels = rasterize_atlas([(uv, np.array([[0, 1, 2]]), _flat(uv), UP)], 10, 10)
    assert len(texels.rows) == 45
    assert ((texels.rows + texels.cols) <= 8).all()
    np.testing.assert_allclose(texels.areas, 0.01)
    np.testing.assert_allclose(texels.positions[:, :2], np.c_[texels.cols + 0.5, texels.rows + 0.5] / 10)


def test_shared_edge_texels_are_counted_once():
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    texels = rasterize_atlas([(uv, faces, _flat(uv) * 3.0, np.tile([0.0, 0.0, 1.0], (4, 1)))], 8, 8)
    assert len(texels.rows) == 64 and texels.mask.all()
    assert texels.areas.sum() == pytest.approx(9.0)


def test_texel_area_sums_to_mesh_area(sphere_texels):
    mesh, _, texels = sphere_texels
    assert texels.areas.sum() == pytest.approx(mesh.area, rel=0.02)


def test_texels_lie_on_their_triangles(sphere_texels):
    mesh, part, texels = sphere_texels
    assert (texels.part == 0).all()
    assert (texels.barycentric >= 0).all()
    np.testing.assert_allclose(texels.barycentric.sum(axis=1), 1.0)
    corners = mesh.vertices[mesh.faces[texels.face]]
    normal = mesh.face_normals[texels.face]
    off_plane = np.einsum("ij,ij->i", texels.positions - corners[:, 0], normal)
    np.testing.assert_allclose(off_plane, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("sk,skd->sd", texels.barycentric, corners), texels.positions, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(texels.normals, axis=1), 1.0)
    assert (np.einsum("ij,ij->i", texels.normals, normal) > 0.9).all()
    # The texel centre, rebuilt from the barycentrics and the UVs, is where the convention says.
    centre = np.einsum("sk,skd->sd", texels.barycentric, part.uvs[part.faces[texels.face]])
    expected = np.c_[(texels.cols + 0.5) / texels.width, (texels.rows + 0.5) / texels.height]
    np.testing.assert_allclose(centre, expected, atol=1e-9)


def test_rows_follow_xatlas_image_rows():
    # xatlas draws chart pixel (x, y) at image row y = v · height: texel lookups must agree.
    mesh = trimesh.creation.icosphere(2)
    atlas = xatlas.Atlas()
    atlas.add_mesh(mesh.vertices.astype(np.float32), mesh.faces.astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution, pack.padding, pack.create_image = 128, 2, True
    atlas.generate(xatlas.ChartOptions(), pack)
    vmapping, faces, uvs = atlas[0]
    texels = rasterize_atlas(
        [(uvs, faces.astype(np.int64), mesh.vertices[vmapping], mesh.vertex_normals[vmapping])],
        atlas.width,
        atlas.height,
    )
    drawn = atlas.chart_image.any(axis=2)
    assert drawn.shape == (atlas.height, atlas.width)
    assert drawn[texels.rows, texels.cols].mean() > 0.99
    assert drawn[atlas.height - 1 - texels.rows, texels.cols].mean() < 0.8


def test_dilate_fills_the_gutter_from_the_nearest_texel():
    image = np.zeros((9, 9, 2))
    mask = np.zeros((9, 9), dtype=bool)
    mask[4, 2], mask[4, 6] = True, True
    image[4, 2], image[4, 6] = (1.0, 10.0), (2.0, 20.0)
    out = dilate(image, mask, 2)
    np.testing.assert_array_equal(out[4, 0:4, 0], [1.0, 1.0, 1.0, 1.0])
    np.testing.assert_array_equal(out[4, 5:9, 1], [20.0, 20.0, 20.0, 20.0])
    assert out[2, 2, 0] == 1.0 and out[1, 2, 0] == 0.0 and out[3, 3, 0] == 1.0
    np.testing.assert_array_equal(out[mask], image[mask])
    np.testing.assert_array_equal(dilate(image, mask, 0), image)
    np.testing.assert_array_equal(dilate(image, np.zeros_like(mask), 3), image)


def test_bad_input_raises():
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(TexelError, match="atlas size"):
        rasterize_atlas([(uv, np.array([[0, 1, 2]]), _flat(uv), UP)], 0, 4)
    with pytest.raises(TexelError, match="part 0 faces"):
        rasterize_atlas([(uv, np.array([[0, 1, 3]]), _flat(uv), UP)], 4, 4)
    with pytest.raises(ValueError, match="dilate mask"):
        dilate(np.zeros((4, 4, 3)), np.zeros((4, 5), dtype=bool), 1)


def test_chunking_does_not_change_the_result(sphere_texels, monkeypatch):
    from sssbake.pipeline.mesh import texels as module

    mesh, part, whole = sphere_texels
    monkeypatch.setattr(module, "CHUNK", 5000)
    chunked = rasterize_atlas(
        [(part.uvs, part.faces, mesh.vertices[part.vmapping], mesh.vertex_normals[part.vmapping])],
        whole.width,
        whole.height,
    )
    for field in ("rows", "cols", "face", "barycentric", "areas"):
        np.testing.assert_array_equal(getattr(chunked, field), getattr(whole, field))
