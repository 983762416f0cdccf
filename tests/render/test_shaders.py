"""The shipped GLSL: every program links in both dialects, and its building blocks equal the numpy
ones (values read back by transform feedback)."""

import moderngl
import numpy as np
import pytest

from sssbake.pipeline.core.directions import octahedral_texel
from sssbake.pipeline.core.fresnel import fresnel_transmittance, schlick_transmittance
from sssbake.pipeline.core.sh import sh_basis
from sssbake.pipeline.render.renderer import draw_kinds
from sssbake.pipeline.render.shaders import shader_source
from sssbake.pipeline.techniques.kernels.runtime import PASS_PROGRAMS as KERNELS_PASSES
from sssbake.pipeline.techniques.lpv.runtime import PASS_PROGRAMS as LPV_PASSES
from sssbake.pipeline.techniques.screen.runtime import PASS_PROGRAMS as SCREEN_PASSES

DIALECTS = ["glsl330", "essl300"]


@pytest.fixture(scope="module")
def ctx():
    context = moderngl.create_standalone_context(backend="egl")
    # Without a bound framebuffer EGL's standalone context silently skips draws, feedback included.
    context.simple_framebuffer((1, 1)).use()
    yield context
    context.release()


def feedback(ctx, library: str, dialect: str, body: str, inputs: np.ndarray, out_floats: int) -> np.ndarray:
    """Run `body` (declaring ``in vec3 in_x`` and ``out ... v_out``) after shader file `library` once
    per row of `inputs` (m, 3); returns (m, out_floats) float32."""
    program = ctx.program(vertex_shader=shader_source(library, dialect) + body, varyings=["v_out"])
    vao = ctx.vertex_array(program, [(ctx.buffer(np.ascontiguousarray(inputs, np.float32).tobytes()), "3f", "in_x")])
    out = ctx.buffer(reserve=len(inputs) * out_floats * 4)
    vao.transform(out, mode=moderngl.POINTS, vertices=len(inputs))
    return np.frombuffer(out.read(), np.float32).reshape(len(inputs), out_floats)


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("kind", sorted(draw_kinds()))
def test_every_program_compiles_and_links(ctx, kind, dialect):
    vertex, fragment = draw_kinds()[kind].program
    program = ctx.program(vertex_shader=shader_source(vertex, dialect), fragment_shader=shader_source(fragment, dialect))
    assert "in_position" in program and "u_view_projection" in program


OFFSCREEN = sorted({pair for passes in (KERNELS_PASSES, SCREEN_PASSES, LPV_PASSES) for pair in passes.values()})


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("vertex, fragment", OFFSCREEN)
def test_every_offscreen_pass_compiles_and_links(ctx, vertex, fragment, dialect):
    program = ctx.program(vertex_shader=shader_source(vertex, dialect), fragment_shader=shader_source(fragment, dialect))
    assert len(list(program)) > 0


def test_dialect_headers_and_includes():
    es = shader_source("prt.vert", "essl300")
    assert es.startswith("#version 300 es\n") and "precision highp usampler2D;" in es
    core = shader_source("prt.vert", "glsl330")
    assert core.startswith("#version 330 core\n") and "#include" not in core
    # prt.vert pulls sss_common.glsl in directly; each file is inlined once
    assert core.count("float fresnel_transmittance(") == 1 and core.count("void sh_basis(") == 1
    with pytest.raises(ValueError, match="dialect"):
        shader_source("prt.vert", "glsl450")
    with pytest.raises(ValueError, match="no shader named"):
        shader_source("missing.glsl")


@pytest.mark.parametrize("dialect", DIALECTS)
def test_fresnel_terms_match_numpy(ctx, dialect):
    eta, cos = np.meshgrid([1.0, 1.3, 1.5, 2.4], np.linspace(-0.2, 1.0, 61))
    x = np.column_stack([eta.ravel(), cos.ravel(), np.zeros(eta.size)])
    body = """
in vec3 in_x;
out vec2 v_out;
void main() { v_out = vec2(fresnel_transmittance(in_x.x, in_x.y), schlick_transmittance(in_x.x, in_x.y)); }
"""
    got = feedback(ctx, "sss_common.glsl", dialect, body, x, 2)
    np.testing.assert_allclose(got[:, 0], fresnel_transmittance(x[:, 0], x[:, 1]), atol=1e-6)
    np.testing.assert_allclose(got[:, 1], schlick_transmittance(x[:, 0], x[:, 1]), atol=1e-6)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_sh_basis_matches_numpy(ctx, dialect):
    d = np.random.default_rng(0).normal(size=(50, 3))
    d = np.vstack([d / np.linalg.norm(d, axis=1, keepdims=True), np.eye(3), -np.eye(3)])
    body = """
in vec3 in_x;
out float v_out[64];
void main() { sh_basis(normalize(in_x), 8, v_out); }
"""
    got = feedback(ctx, "sh_basis.glsl", dialect, body, d, 64)
    np.testing.assert_allclose(got, sh_basis(d, 8), atol=2e-5)


@pytest.mark.parametrize("size", [7, 64])
def test_octahedral_texel_matches_numpy(ctx, size):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(300, 3))
    # axes, diagonals and the folded edges (x or y = 0 below the equator) included
    extra = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [1, 1, -1],
                      [-1, 0, -1], [0, -1, -1], [1, -1, 0.0]])
    d = np.vstack([d, extra])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    body = f"""
in vec3 in_x;
out vec2 v_out;
void main() {{ v_out = vec2(prt_octahedral_texel(in_x, {size})); }}
"""
    got = feedback(ctx, "prt_decode.glsl", "glsl330", body, d, 2)
    np.testing.assert_array_equal(got.astype(np.int64), octahedral_texel(d, size))


def test_degenerate_vectors_stay_finite(ctx):
    # a zero normal, and the eye exactly opposite the light (v + l = 0)
    body = """
in vec3 in_x;
out vec3 v_out;
void main() {
    vec3 l = vec3(0.0, 0.0, 1.0);
    v_out = vec3(surface_specular(sss_normalize(in_x), -l, l, 1.3, 64.0),
                 surface_specular(l, -l, l, 1.3, 64.0), length(sss_normalize(in_x)));
}
"""
    got = feedback(ctx, "sss_common.glsl", "glsl330", body, np.zeros((2, 3)), 3)
    assert np.all(np.isfinite(got)) and np.all(got == 0.0)
