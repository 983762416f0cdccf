"""The reference runtime renders closed-form radiance, decodes prt data as numpy does, and gives
the same image in both GLSL dialects."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.decode import evaluate

QUAD = (np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
# rotation about (1, 2, 3), non-uniform scale and a shift: q is tabulated in object space
MODEL = np.eye(4)
MODEL[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3] @ np.diag([1.2, 0.9, 1.0])
MODEL[:3, 3] = [0.3, -0.2, 0.1]


@pytest.fixture(scope="module")
def renderers():
    made = {d: Renderer((64, 64), d, table_width=5) for d in ("glsl330", "essl300")}
    yield made
    for r in made.values():
        r.release()


def quad_item(**kind):
    v, f = QUAD
    return dict(positions=v, normals=np.tile([0, 0, 1.0], (4, 1)), faces=f, model=np.eye(4), eta=1.3, **kind)


def random_prt(n: int, rng, k: int = 40, refs: int = 30, ref_triangles: int = 70_000, order: int = 3,
               channels: int = 3, weight_bits: int = 16) -> PrtData:
    """Valid PrtData with random codes, RGB (`channels` 3) or shared tables (1), 16- or 8-bit
    weights; by default more reference triangles than 65536 so that ``_SSS_PRT_REF``'s high half
    is used."""
    top = (1 << (weight_bits - 1)) - 1
    ds = direction_set(k, lookup_size=16)
    c = order * order
    vertex_triangle = rng.integers(0, ref_triangles, n).astype(np.int32)
    vertex_triangle[0] = ref_triangles - 1
    return PrtData(
        directions=ds.directions.astype(np.float32), direction_triangles=ds.triangles.astype(np.int32),
        direction_inverse=ds.inverse.astype(np.float32), direction_lookup=ds.lookup.astype(np.int32),
        direction_neighbours=ds.neighbours.astype(np.int32),
        lut=np.sort(rng.uniform(0.0, 2.0, (3, 256)), axis=1).astype(np.float32),
        ref_vertices=np.arange(refs, dtype=np.int64),
        ref_codes=rng.integers(0, 256, (refs, k, channels), dtype=np.uint8),
        ref_scale=rng.uniform(0.2, 1.5, (refs if channels == 1 else 0, 3)).astype(np.float32),
        ref_triangles=rng.integers(0, refs, (ref_triangles, 3), dtype=np.int32),
        vertex_triangle=vertex_triangle,
        weight_codes=rng.integers(-top // 4, top * 2 // 3, (n, 2)).astype(np.int16), weight_scale=1.5,
        weight_bits=weight_bits, dq_codes=rng.integers(-127, 128, (n, 3, c), dtype=np.int8),
        dq_scale=rng.uniform(0.0, 0.3, (3, c)).astype(np.float32), sh_order=order, eta=1.4)


def sphere_item(rng, channels: int = 3, weight_bits: int = 16):
    s = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(s.vertices)
    # 8-bit weights address 65536 triangles at most: the top byte of the 16-bit index is used
    triangles = 70_000 if weight_bits == 16 else 65_536
    return dict(positions=v, normals=v, faces=np.asarray(s.faces), model=MODEL, eta=1.4,
                prt=random_prt(len(v), rng, ref_triangles=triangles, channels=channels, weight_bits=weight_bits))


def cpu_q(item, light: RenderLight) -> np.ndarray:
    """(n, 3) what prt.vert computes per vertex, from the numpy decoder."""
    model = item["model"]
    world = item["positions"] @ model[:3, :3].T + model[:3, 3]
    if light.point:
        to_light = np.asarray(light.vector) - world
        d = np.linalg.norm(to_light, axis=1, keepdims=True)
        irradiance = light.intensity / (d * light.mm_per_unit) ** 2
        towards = to_light / d
    else:
        irradiance = light.intensity
        towards = np.broadcast_to(np.asarray(light.vector) / np.linalg.norm(light.vector), world.shape)
    omega = np.linalg.solve(model[:3, :3], towards.T).T
    omega /= np.linalg.norm(omega, axis=1, keepdims=True)
    return irradiance * np.clip(evaluate(item["prt"], omega).T, 0.0, None)


@pytest.mark.parametrize("dialect", ["glsl330", "essl300"])
def test_constant_radiance_leaves_through_the_exit_fresnel(renderers, dialect):
    camera = fit_camera(QUAD[0], view_dir=(0, 0, -1))
    image, mask = renderers[dialect].render([quad_item(q=np.tile([0.2, 0.4, 0.6], (4, 1)))], camera, RenderLight())
    # the centre pixel looks straight down the normal
    np.testing.assert_allclose(image[32, 32], np.array([0.2, 0.4, 0.6]) * fresnel_transmittance(1.3, 1.0), rtol=1e-5)
    assert mask[32, 32] and not mask[0, 0]


def test_surface_terms_have_their_closed_forms(renderers):
    r = renderers["glsl330"]
    camera = fit_camera(QUAD[0], view_dir=(0, 0, -1))
    light = RenderLight(False, (0, 0, 1), 2.0)
    albedo = np.array([0.5, 0.25, 1.0])
    spec = (1 - fresnel_transmittance(1.3, 1.0)) * (64 + 8) / (8 * np.pi)  # Blinn-Phong peak, per unit irradiance
    # scattering off: only the surface terms remain, lit and seen along the normal
    image, _ = r.render([quad_item(q=np.zeros((4, 3)))], camera, light, specular=1.0, diffuse=albedo)
    np.testing.assert_allclose(image[32, 32], 2.0 * (spec + albedo / np.pi), rtol=1e-3)
    plain, _ = r.render([quad_item(albedo=albedo)], camera, light, specular=1.0)
    np.testing.assert_allclose(plain[32, 32], image[32, 32], rtol=1e-5)


def test_sphere_coverage_matches_its_silhouette(renderers):
    s = trimesh.creation.icosphere(subdivisions=4)
    v, f = np.asarray(s.vertices), np.asarray(s.faces)
    camera = fit_camera(v, view_dir=(0, 0, -1), fov_degrees=30)
    item = dict(positions=v, normals=v, faces=f, model=np.eye(4), eta=1.3, albedo=(1.0, 1.0, 1.0))
    _, mask = renderers["glsl330"].render([item], camera, RenderLight())
    # a sphere seen from distance d subtends a disc of radius tan(asin(1/d)) / tan(15°) half-heights
    d = np.linalg.norm(np.asarray(camera.eye))
    r = np.tan(np.arcsin(1.0 / d)) / np.tan(np.radians(15.0))
    assert mask.mean() == pytest.approx(np.pi * r * r / 4.0, rel=0.03)


@pytest.mark.parametrize("light, channels, bits", [(RenderLight(False, (0.3, 0.8, 0.5), 1.5), 3, 16),
                                                   (RenderLight(True, (1.5, 2.5, 2.0), 40.0, mm_per_unit=2.0), 1, 8)],
                         ids=["directional-rgb-16", "point-shared-8"])
def test_prt_decode_on_the_gpu_matches_numpy(renderers, light, channels, bits):
    # wrapped tables (width 5), a 65536- or 70000-triangle reference mesh, an object-to-world transform
    rng = np.random.default_rng(7)
    item = sphere_item(rng, channels, bits)
    camera = fit_camera(item["positions"] @ MODEL[:3, :3].T + MODEL[:3, 3], view_dir=(-0.2, -0.3, -1))
    r = renderers["glsl330"]
    gpu, mask = r.render([item], camera, light)
    reference = {k: v for k, v in item.items() if k != "prt"}
    cpu, cpu_mask = r.render([{**reference, "q": cpu_q(item, light)}], camera, light)
    assert np.array_equal(mask, cpu_mask) and mask.mean() > 0.2
    np.testing.assert_allclose(gpu, cpu, atol=2e-5 * cpu.max())


def test_dialects_render_the_same_image(renderers):
    item = sphere_item(np.random.default_rng(8))
    camera = fit_camera(item["positions"], view_dir=(0.1, -0.5, -1))
    light = RenderLight(True, (1.0, 2.0, 3.0), 10.0)
    core, _ = renderers["glsl330"].render([item], camera, light, specular=0.5)
    es, _ = renderers["essl300"].render([item], camera, light, specular=0.5)
    assert core.max() > 0
    np.testing.assert_allclose(es, core, atol=1e-5 * core.max())


def test_frame_time_is_measured(renderers):
    camera = fit_camera(QUAD[0], view_dir=(0, 0, -1))
    r = renderers["glsl330"]
    for item in (quad_item(q=np.ones((4, 3))), quad_item(albedo=(1, 1, 1)), sphere_item(np.random.default_rng(0))):
        assert 0.0 < r.frame_ms([item], camera, RenderLight(), frames=3) < 1000.0


def test_bad_input_gets_a_clear_error(renderers):
    r = renderers["glsl330"]
    camera = fit_camera(QUAD[0])
    with pytest.raises(ValueError, match="q must be finite with shape"):
        r.render([quad_item(q=np.ones((3, 4)))], camera, RenderLight())
    with pytest.raises(ValueError, match="faces must be"):
        r.render([{**quad_item(q=np.ones((4, 3))), "faces": np.array([[0, 1, 4]])}], camera, RenderLight())
    with pytest.raises(ValueError, match="exactly one of"):
        r.render([quad_item()], camera, RenderLight())
    with pytest.raises(ValueError, match="light vector"):
        RenderLight(False, (0, 0, 0))
    with pytest.raises(ValueError, match="outside"):
        Renderer((100_000, 64))
    with pytest.raises(ValueError, match="positions"):
        fit_camera(np.zeros((0, 3)))


def test_tables_beyond_the_texture_limit_are_refused():
    item = sphere_item(np.random.default_rng(1))
    r = Renderer((8, 8), table_width=1)  # a 1-texel-wide layout of 70000 triangles: too tall
    try:
        with pytest.raises(ValueError, match="GL_MAX_TEXTURE_SIZE"):
            r.render([item], fit_camera(item["positions"]), RenderLight())
    finally:
        r.release()
