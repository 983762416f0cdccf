"""The kernels runtime on the GPU: the illumination map has its closed form at every texel (atlas
orientation, shadows, border texels), the filter and gather passes equal `kernels_evaluate`, and
the final draw equals a per-vertex draw of the same response."""

import dataclasses

import numpy as np
import pytest
import trimesh
from fixtures import random_kernels

from sssbake.pipeline.core.fresnel import schlick_transmittance
from sssbake.pipeline.mesh.texels import rasterize_atlas
from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
from sssbake.pipeline.techniques.kernels.data import KernelsData
from sssbake.pipeline.techniques.kernels.evaluate import local_response, vertex_response
from sssbake.pipeline.techniques.kernels.runtime import wrap_width

DIALECTS = ["glsl330", "essl300"]
# rotation about (1, 2, 3), non-uniform scale and a shift
MODEL = np.eye(4)
MODEL[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3] @ np.diag([1.2, 0.9, 1.0])
MODEL[:3, 3] = [0.3, -0.2, 0.1]
ETA = 1.4


@pytest.fixture(scope="module")
def renderers():
    # a 7-texel table width wraps every table (the per-vertex ones with a partial last row)
    made = {d: Renderer((48, 48), d, table_width=7, shadow_size=1024) for d in DIALECTS}
    yield made
    for r in made.values():
        r.release()


def atlas_kernels(width, height, n, texels, border_texels=(), border_vertices=(), border_barycentric=()):
    """KernelsData over `texels` with zero weights (what the light passes do not read)."""
    s = len(texels)
    data = KernelsData(
        width=width, height=height, kernel_size=3, vertex_count=n, texels=np.asarray(texels, np.int64),
        kernels=np.zeros((s, 9, 3), np.float32), texel_vertices=np.zeros((s, 3), np.int64),
        texel_dual=np.zeros((s, 3), np.float32), texel_direct=np.zeros((s, 3, 3), np.float32),
        f_indptr=np.zeros(n + 1, np.int64), f_indices=np.zeros(0, np.int64), f_values=np.zeros((0, 3), np.float32),
        border_texels=np.asarray(border_texels, np.int64),
        border_vertices=np.asarray(border_vertices, np.int64).reshape(-1, 3),
        border_barycentric=np.asarray(border_barycentric, np.float32).reshape(-1, 3), surface_vertex_count=n,
        surface_global=np.repeat(np.arange(n)[:, None], 3, axis=1), surface_weights=np.tile([1.0, 0, 0], (n, 1)))
    data.check()
    return data


def world(points, normals, model=MODEL):
    """Object-space points and normals to world space (normals unit)."""
    n = normals @ np.linalg.inv(model[:3, :3])
    return points @ model[:3, :3].T + model[:3, 3], n / np.linalg.norm(n, axis=-1, keepdims=True)


def closed_form(points, normals, light: RenderLight, eta=ETA):
    """E = F_t(η, n·l) max(0, n·l) irradiance / π at unshadowed world points with unit normals."""
    if light.point:
        to_light = np.asarray(light.vector) - points
        d = np.linalg.norm(to_light, axis=-1, keepdims=True)
        irradiance = light.intensity / np.maximum(d[..., 0] * light.mm_per_unit, 1e-3) ** 2
        towards = to_light / d
    else:
        irradiance = light.intensity
        towards = np.asarray(light.vector) / np.linalg.norm(light.vector)
    cos = np.clip(np.sum(normals * towards, axis=-1), 0.0, None)
    return schlick_transmittance(eta, cos) * cos * irradiance / np.pi


def centres(width, height):
    """(height, width, 2) UV of every texel centre."""
    rows, cols = np.mgrid[:height, :width]
    return np.stack([(cols + 0.5) / width, (rows + 0.5) / height], axis=-1)


def quad(uv_lo, uv_hi, to_object):
    """A UV rectangle as two triangles, object positions ``to_object(uv)``, normal +z."""
    uvs = np.array([[uv_lo[0], uv_lo[1]], [uv_hi[0], uv_lo[1]], [uv_hi[0], uv_hi[1]], [uv_lo[0], uv_hi[1]]])
    return uvs, to_object(uvs), np.tile([0.0, 0.0, 1.0], (4, 1)), np.array([[0, 1, 2], [0, 2, 3]])


def item_of(uvs, positions, normals, faces, data, vertex_ids=None, model=MODEL):
    ids = np.arange(len(uvs)) if vertex_ids is None else vertex_ids
    return dict(positions=positions, normals=normals, faces=faces, uvs=uvs, vertex_ids=ids, model=model, eta=ETA,
                kernels=data)


# The quad covers the upper part of a 20 x 14 atlas: flipping v would light rows 7-12 instead of
# 1-6. Object position (3u, -2v, 0): every texel centre's surface point is known.
QUAD_LO, QUAD_HI, QUAD_SIZE = (0.13, 0.09), (0.71, 0.47), (20, 14)


def quad_to_object(uv):
    return np.column_stack([3.0 * uv[..., 0], -2.0 * uv[..., 1], np.zeros(len(uv))])


def quad_lights():
    corner, normal = world(quad_to_object(np.array([QUAD_LO]))[0], np.array([0.0, 0.0, 1.0]))
    tangent = np.cross(normal, [1.0, 0.0, 0.0])
    return [RenderLight(False, tuple(normal + 0.6 * tangent), 1.7),
            # close to one corner: irradiance and direction vary across the quad
            RenderLight(True, tuple(corner + 0.4 * normal + 0.1 * tangent), 30.0, mm_per_unit=2.0)]


@pytest.mark.parametrize("light_index", [0, 1], ids=["directional", "point"])
def test_illumination_map_has_its_closed_form_at_every_texel(renderers, light_index):
    light = quad_lights()[light_index]
    width, height = QUAD_SIZE
    uv = centres(width, height)
    inside = np.all((uv > QUAD_LO) & (uv < QUAD_HI), axis=-1)
    assert inside[1:7].any() and not inside[7:].any()
    uvs, positions, normals, faces = quad(QUAD_LO, QUAD_HI, quad_to_object)
    data = atlas_kernels(width, height, 4, np.flatnonzero(inside))
    e = renderers["glsl330"].passes(item_of(uvs, positions, normals, faces, data), light)["illumination"]
    points, n = world(quad_to_object(uv[inside]), np.array([0.0, 0.0, 1.0]))
    expected = np.zeros((height, width))
    expected[inside] = closed_form(points, n, light)
    assert expected[inside].min() > 0
    if light.point:
        assert np.ptp(expected[inside]) > 0.5 * expected.max()
    np.testing.assert_allclose(e, expected, rtol=2e-5, atol=1e-6 * expected.max())


@pytest.mark.parametrize("light", [RenderLight(False, (0.3, 0.0, 1.0), 2.0), RenderLight(True, (0.5, 0.0, 3.0), 50.0)],
                         ids=["directional", "point"])
def test_an_occluder_shadows_the_plane_below_it(renderers, light):
    # plane z = 0 over [-1, 1]² in the left half of a 48 x 24 atlas, occluder z = 0.4 over x < 0
    # in the right half; the shadow's edge on the plane: x = -0.12 (directional), -0.08 (point)
    width, height = 48, 24
    plane = quad((0.0, 0.0), (0.5, 1.0), lambda uv: np.column_stack([4 * uv[:, 0] - 1, 1 - 2 * uv[:, 1], 0 * uv[:, 0]]))
    cover = quad((0.55, 0.05), (0.95, 0.95), lambda uv: np.column_stack([3.25 * (uv[:, 0] - 0.55) - 1.3,
                                                                          1.3 - 2.6 / 0.9 * (uv[:, 1] - 0.05),
                                                                          0 * uv[:, 0] + 0.4]))
    uvs, positions, normals = (np.concatenate([plane[i], cover[i]]) for i in range(3))
    faces = np.concatenate([plane[3], cover[3] + 4])
    uv = centres(width, height)
    on_plane = uv[..., 0] < 0.5
    data = atlas_kernels(width, height, 8, np.flatnonzero(on_plane | np.all((uv > 0.55) & (uv < 0.95), axis=-1)))
    item = item_of(uvs, positions, normals, faces, data, model=np.eye(4))
    e = renderers["glsl330"].passes(item, light)["illumination"]
    x = 4 * uv[..., 0] - 1
    points = np.stack([x, 1 - 2 * uv[..., 1], np.zeros_like(x)], axis=-1)
    lit = closed_form(points, np.broadcast_to([0.0, 0.0, 1.0], points.shape), light)
    shadowed, unshadowed = on_plane & (x < -0.3), on_plane & (x > 0.3)
    assert shadowed.sum() > 100 and unshadowed.sum() > 100
    assert np.all(e[shadowed] == 0.0)
    np.testing.assert_allclose(e[unshadowed], lit[unshadowed], rtol=2e-5)


def test_border_texels_get_the_light_of_their_surface_point(renderers):
    # welded tent 0-1-2-3 (a crease along 1-2); render triangle (0, 1, 2) in the atlas, its
    # neighbour (2, 1, 3) only as border texels beside it; welded 1 and 2 have two render vertices
    welded = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.3], [0.0, 1.0, 0.3], [1.0, 1.0, 0.0]])
    welded_normals = np.array([[-0.3, -0.3, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.3, 0.3, 1.0]])
    welded_normals /= np.linalg.norm(welded_normals, axis=1, keepdims=True)
    vertex_ids = np.array([0, 1, 2, 2, 1, 3])
    uvs = np.array([[0.05, 0.05], [0.45, 0.05], [0.05, 0.75], [0.9, 0.1], [0.9, 0.9], [0.6, 0.9]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    width, height = 16, 12
    samples = rasterize_atlas([(uvs, faces, welded[vertex_ids], welded_normals[vertex_ids])], width, height)
    texels = samples.rows * width + samples.cols
    free = np.setdiff1d(np.arange(width * height), texels)
    rng = np.random.default_rng(3)
    border = np.sort(rng.choice(free, 12, replace=False))
    bary = rng.dirichlet(np.ones(3), len(border))
    data = atlas_kernels(width, height, 4, texels, border, np.tile([2, 1, 3], (len(border), 1)), bary)
    centre, up = world(welded.mean(axis=0), np.array([0.0, 0.0, 1.0]))
    light = RenderLight(True, tuple(centre + 1.2 * up), 20.0)
    item = item_of(uvs, welded[vertex_ids], welded_normals[vertex_ids], faces, data, vertex_ids)
    e = renderers["essl300"].passes(item, light)["illumination"].reshape(-1)
    expected = np.zeros(width * height)
    expected[texels] = closed_form(*world(samples.positions, samples.normals), light)
    expected[border] = closed_form(*world(bary @ welded[[2, 1, 3]], bary @ welded_normals[[2, 1, 3]]), light)
    assert expected[border].min() > 0
    np.testing.assert_allclose(e, expected, rtol=2e-5, atol=1e-6 * expected.max())


def random_item(rng, data: KernelsData):
    """Render arrays for `data` (what passes 3-4 do not read): one render vertex per welded one."""
    n = data.vertex_count
    positions = rng.normal(size=(n, 3))
    return item_of(rng.uniform(0, 1, (n, 2)), positions, positions, rng.integers(0, n, (20, 3)), data)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_filter_and_gather_passes_equal_numpy(renderers, dialect):
    rng = np.random.default_rng(5)
    data = random_kernels(rng)
    e = rng.uniform(0.0, 2.0, (data.height, data.width))  # border and empty texels too: the filter reads them
    out = renderers[dialect].passes(random_item(rng, data), RenderLight(), given=e)
    np.testing.assert_array_equal(out["illumination"], e.astype(np.float32))
    e_g, b_d, b_g = vertex_response(data, e)
    for name, cpu in (("local", local_response(data, e)), ("e_g", e_g), ("b_d", b_d), ("b_g", b_g)):
        assert out[name].shape == cpu.shape
        np.testing.assert_allclose(out[name], cpu, rtol=1e-4, atol=1e-6 * np.abs(cpu).max(), err_msg=name)


def grid_item(rng):
    """A bent 5 x 5 grid, unwelded (three render vertices per triangle, vertex_ids the welded
    ones), UV-mapped onto part of a 24 x 18 atlas; random distribution and F weights, zero kernels."""
    g = np.linspace(0.0, 1.0, 5)
    x, y = np.meshgrid(g, g)
    welded = np.column_stack([x.ravel(), y.ravel(), 0.3 * np.sin(2 * x.ravel()) * y.ravel()])
    idx = np.arange(25).reshape(5, 5)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    welded_faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    normals = trimesh.Trimesh(welded, welded_faces, process=False).vertex_normals
    ids = welded_faces.reshape(-1)
    uvs = np.column_stack([0.1 + 0.6 * welded[ids, 0], 0.15 + 0.5 * welded[ids, 1]])
    faces = np.arange(len(ids)).reshape(-1, 3)
    width, height = 24, 18
    samples = rasterize_atlas([(uvs, faces, welded[ids], normals[ids])], width, height)
    data = random_kernels(rng, n=25, width=width, height=height, kernel_size=3, texels=len(samples.rows), borders=0)
    data = dataclasses.replace(data, texels=samples.rows * width + samples.cols, kernels=np.zeros_like(data.kernels))
    return item_of(uvs, welded[ids], normals[ids], faces, data, ids, model=np.eye(4))


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("local", [False, True], ids=["vertex-only", "with-local"])
def test_final_image_adds_the_local_response_to_the_vertex_response(renderers, dialect, local):
    r = renderers[dialect]
    rng = np.random.default_rng(11)
    item = grid_item(rng)
    data = item["kernels"]
    light = RenderLight(False, (0.2, -0.3, 1.0), 1.5)
    out = r.passes(item, light)
    e = out["illumination"].astype(np.float64)
    assert np.all(e.reshape(-1)[data.texels] > 0)
    # passes 1-4 chained: the GPU's response to its own E is numpy's
    e_g, b_d, b_g = vertex_response(data, e)
    for name, cpu in (("e_g", e_g), ("b_d", b_d), ("b_g", b_g)):
        np.testing.assert_allclose(out[name], cpu, rtol=1e-4, atol=1e-6 * np.abs(cpu).max(), err_msg=name)
    q = (b_g + b_d)[item["vertex_ids"]]
    if local:  # and each welded vertex blends three global vertices (a simplified global mesh)
        n = data.surface_vertex_count
        data = dataclasses.replace(data, surface_global=rng.integers(0, data.vertex_count, (n, 3)),
                                   surface_weights=rng.dirichlet(np.ones(3), n).astype(np.float32))
        ids = item["vertex_ids"]
        q = np.einsum("vk,vkc->vc", data.surface_weights[ids], (b_g + b_d)[data.surface_global[ids]])
        # centre weights c / E make B_l = c on every covered texel, so its coverage-normalised
        # bilinear read is c wherever the surface is (a flipped or shifted read would find none)
        c = np.array([0.05, 0.1, 0.2])
        kernels = np.zeros_like(data.kernels)
        kernels[:, 4, :] = c / e.reshape(-1)[data.texels, None]
        item = {**item, "kernels": dataclasses.replace(data, kernels=kernels.astype(np.float32))}
        np.testing.assert_allclose(r.passes(item, light)["local"], np.tile(c, (len(data.texels), 1)),
                                   rtol=1e-5)
        q = q + c
    camera = fit_camera(item["positions"], view_dir=(0.1, 0.2, -1.0))
    image, mask = r.render([item], camera, light, specular=0.3)
    reference = {k: v for k, v in item.items() if k not in ("kernels", "uvs", "vertex_ids")}
    expected, expected_mask = r.render([{**reference, "q": q}], camera, light, specular=0.3)
    assert np.array_equal(mask, expected_mask) and mask.mean() > 0.2
    np.testing.assert_allclose(image, expected, atol=1e-5 * expected.max())


def test_frame_time_covers_a_kernels_item(renderers):
    item = grid_item(np.random.default_rng(2))
    r = renderers["glsl330"]
    assert 0.0 < r.frame_ms([item], fit_camera(item["positions"]), RenderLight(), frames=3) < 1000.0


def test_bad_kernels_items_get_a_clear_error(renderers):
    r = renderers["glsl330"]
    item = grid_item(np.random.default_rng(4))
    camera, light = fit_camera(item["positions"]), RenderLight()
    with pytest.raises(ValueError, match="vertex_ids must be"):
        r.render([{**item, "vertex_ids": item["vertex_ids"] + 1}], camera, light)
    with pytest.raises(ValueError, match="uvs must be finite with shape"):
        r.render([{**item, "uvs": item["uvs"][:, :1]}], camera, light)
    with pytest.raises(ValueError, match="kernels must be KernelsData"):
        r.render([{**item, "kernels": None}], camera, light)
    bad = dataclasses.replace(item["kernels"], f_values=item["kernels"].f_values[:1])
    with pytest.raises(ValueError, match="item 0: kernels: f_values has shape"):
        r.render([{**item, "kernels": bad}], camera, light)
    with pytest.raises(ValueError, match="illumination must be finite with shape"):
        r.passes(item, light, given=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="a q item has no offscreen passes"):
        r.passes({**{k: v for k, v in item.items() if k != "kernels"}, "q": item["normals"]}, light)
    # welded vertex 24 (a corner) in a border texel, yet no render vertex maps to it
    data = dataclasses.replace(item["kernels"], border_texels=np.array([0]), border_vertices=np.array([[0, 1, 24]]),
                               border_barycentric=np.full((1, 3), 1 / 3))
    keep = item["vertex_ids"] != 24
    m = int(keep.sum())
    partial = {**item, "kernels": data, "faces": np.arange(m - m % 3).reshape(-1, 3),
               **{k: item[k][keep] for k in ("positions", "normals", "uvs", "vertex_ids")}}
    with pytest.raises(ValueError, match="no render vertex maps to"):
        r.render([partial], camera, light)


def test_tables_taller_than_the_texture_limit_are_widened():
    # 400 · 49 kernel weights asked for one column: the table widens until its rows fit the
    # limit, and the passes still equal numpy
    rng = np.random.default_rng(6)
    r = Renderer((8, 8), table_width=1, shadow_size=16)
    try:
        limit = r.ctx.info["GL_MAX_TEXTURE_SIZE"]
        data = random_kernels(rng, texels=400)
        e = rng.uniform(0.0, 2.0, (data.height, data.width))
        out = r.passes(random_item(rng, data), RenderLight(), given=e)
        np.testing.assert_allclose(out["local"], local_response(data, e), rtol=1e-4,
                                   atol=1e-6 * np.abs(local_response(data, e)).max())
        assert wrap_width(400 * 49, 1, limit) == -(-400 * 49 // limit) >= 2
        wide = random_kernels(rng, width=limit + 1, height=1, texels=10, borders=0)
        with pytest.raises(ValueError, match="atlas is over GL_MAX_TEXTURE_SIZE"):
            r.passes(random_item(rng, wide), RenderLight())
    finally:
        r.release()


def test_wrap_width_keeps_every_side_within_the_limit():
    for count, width, limit in [(10, 4, 16), (100, 4, 16), (256, 4, 16), (257, 4, 16), (3, 4, 16), (0, 4, 16)]:
        w = wrap_width(count, width, limit)
        assert 1 <= w <= limit
        if count <= limit * limit:
            assert -(-count // w) <= limit  # rows fit
            assert w == max(min(width, max(count, 1)), -(-count // limit))  # no wider than needed
    assert wrap_width(100, 4, 16) == 7 and wrap_width(10, 4, 16) == 4
    assert wrap_width(300, 4, 16) == 16  # over limit²: the caller refuses it
