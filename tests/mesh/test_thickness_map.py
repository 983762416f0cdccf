"""The thickness texture: whole 4x4 blocks, and where texture and vertices both hold thickness they agree."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.mesh.atlas import BLOCK, compute_atlas
from sssbake.pipeline.mesh.clean import weld_surface
from sssbake.pipeline.mesh.scene import Primitive
from sssbake.pipeline.mesh.thickness import bake_thickness
from sssbake.pipeline.mesh.thickness_map import bake_thickness_map


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(n,) LINEAR-filtered, CLAMP_TO_EDGE lookups of (H, W) `image` at (n, 2) glTF UVs (texel centres at +0.5)."""
    h, w = image.shape
    x, y = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0

    def at(r, c):
        return image[np.clip(r, 0, h - 1), np.clip(c, 0, w - 1)]

    return ((1 - fx) * (1 - fy) * at(y0, x0) + fx * (1 - fy) * at(y0, x0 + 1)
            + (1 - fx) * fy * at(y0 + 1, x0) + fx * fy * at(y0 + 1, x0 + 1))


@pytest.mark.parametrize("resolution", [128, 250])
def test_texture_is_whole_blocks_and_matches_vertex_thickness(resolution):
    # an ellipsoid 4 x 2 x 1: thickness along the inward normal varies smoothly from ~1 to ~4
    sphere = trimesh.creation.icosphere(2)
    positions = np.asarray(sphere.vertices) * [2.0, 1.0, 0.5]
    faces = np.asarray(sphere.faces, dtype=np.int64)
    normals = np.asarray(trimesh.Trimesh(positions, faces, process=False).vertex_normals, dtype=np.float64)
    prim = Primitive(positions, faces, normals=normals)
    atlas = compute_atlas([(positions, faces)], resolution=resolution, padding=2)
    assert atlas.width % BLOCK == 0 and atlas.height % BLOCK == 0
    surface = weld_surface([prim], 1e-9)
    cap = 10.0
    tmap = bake_thickness_map(atlas, [(positions, normals)], surface, cap=cap, rays=1, padding=2)
    assert tmap.image.shape == (atlas.height, atlas.width) and tmap.escaped == 0
    # the per-vertex bake at each face centre, along its interpolated normal (what a texel there gets)
    part = atlas.parts[0]
    centres = positions[faces].mean(axis=1)
    inward = -normals[faces].mean(axis=1)
    expected = bake_thickness(surface.positions, surface.faces, origins=centres,
                              directions=inward / np.linalg.norm(inward, axis=1, keepdims=True), cap=cap,
                              rays=1).thickness
    assert expected.min() < 1.5 and expected.max() > 3.0
    # the texture read with the written LINEAR filter at each face centre's atlas UV
    error = np.abs(bilinear(tmap.image, part.uvs[part.faces].mean(axis=1)) / expected - 1.0)
    # texels sample the surface at their centres, not at the faces': faces next to a chart's border
    # read gutter copies, up to 6 % off at 128 texels (3 % at 250); most agree to rounding
    assert np.median(error) < 0.002 and error.max() < 0.08, np.quantile(error, [0.5, 0.99, 1.0])


def test_a_textured_cube_reads_its_edge_at_every_texel():
    # render vertices split at every edge (each triangle its own three), so are the normals: every
    # texel casts along its face's normal
    box = trimesh.creation.box(extents=(100.0, 100.0, 100.0))
    positions = np.asarray(box.vertices, dtype=np.float64)[np.asarray(box.faces)].reshape(-1, 3)
    faces = np.arange(len(positions), dtype=np.int64).reshape(-1, 3)
    normals = np.repeat(np.asarray(box.face_normals, dtype=np.float64), 3, axis=0)
    atlas = compute_atlas([(positions, faces)], resolution=64, padding=2)
    surface = weld_surface([Primitive(positions, faces, normals=normals)], 1e-9)
    tmap = bake_thickness_map(atlas, [(positions, normals)], surface, cap=1000.0, rays=1, padding=2)
    assert tmap.mask.sum() > 1000 and tmap.escaped == 0
    np.testing.assert_allclose(tmap.image[tmap.mask], 100.0, rtol=1e-9)
