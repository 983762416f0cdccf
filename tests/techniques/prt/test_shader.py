"""The shipped GLSL decodes prt data exactly as the numpy decoder does, in both dialects."""

import moderngl
import numpy as np
import pytest

from sssbake.pipeline.core.sh import sh_basis
from sssbake.pipeline.render.shaders import shader_source
from sssbake.pipeline.techniques.prt.compress import PrtCompressOptions, compress_prt, evaluate
from sssbake.pipeline.techniques.prt.runtime import per_vertex_arrays, upload

# A driver for transform feedback: decode every vertex for one light direction per vertex.
DRIVER = """#include "prt_decode.glsl"
in vec3 in_dir;
out vec3 v_q;
void main() { v_q = prt_decode(gl_VertexID, normalize(in_dir)); }
"""


@pytest.fixture(scope="module")
def ctx():
    context = moderngl.create_standalone_context(backend="egl")
    # EGL's standalone context has no default framebuffer; without one bound, draws (transform
    # feedback included) silently do nothing.
    context.simple_framebuffer((1, 1)).use()
    return context


def _source(dialect: str, prelude: str) -> str:
    from sssbake.pipeline.render import shaders

    original = shaders._expand

    def expand(name, seen):
        return DRIVER.replace('#include "prt_decode.glsl"', original("prt_decode.glsl", seen)) if name == "driver" \
            else original(name, seen)

    shaders._expand = expand
    try:
        return shader_source("driver", dialect, prelude)
    finally:
        shaders._expand = original


def decode_on_gpu(ctx, prt, directions, dialect="glsl330", width=4096):
    # the SH order as a uniform here (the renderer compiles a variant per order)
    compact = "#define PRT_COMPACT\n" if prt.weight_bits == 8 else ""
    program = ctx.program(vertex_shader=_source(dialect, compact), varyings=["v_q"])
    textures = upload(ctx, program, prt, width=width)
    n = prt.vertex_count
    buffers = [(ctx.buffer(a.tobytes()), fmt, name) for a, fmt, name in per_vertex_arrays(prt)]
    buffers.append((ctx.buffer(np.ascontiguousarray(directions, np.float32).tobytes()), "3f", "in_dir"))
    vao = ctx.vertex_array(program, [b for b in buffers if b[2] in program])
    out = ctx.buffer(reserve=n * 12)
    vao.transform(out, mode=moderngl.POINTS, vertices=n)
    result = np.frombuffer(out.read(), dtype=np.float32).reshape(n, 3).T
    for t in textures:
        t.release()
    return result


@pytest.mark.parametrize("dialect", ["glsl330", "essl300"])
@pytest.mark.parametrize("options", [PrtCompressOptions(sh_order=3, weights="least_squares"),
                                     PrtCompressOptions(sh_order=2, tables="rgb", weight_bits=16),
                                     PrtCompressOptions(),
                                     PrtCompressOptions(detail_order=4, reference_fraction=0.3),
                                     PrtCompressOptions(mode="sh", sh_order=8, dq_percentile=100),
                                     PrtCompressOptions(mode="lloyd")])
def test_glsl_decode_matches_numpy(ctx, blob, dialect, options):
    v, f, ds, q = blob
    prt = compress_prt(q, ds, v, f, 1.3, options)
    shared = len(prt.ref_scale) > 0  # what tables="auto" chose: shared tables carry a colour per point
    assert prt.detail_order == (options.detail_order if options.mode == "refs+sh" and shared else 0)
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(len(v), 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    # a tiny table width forces the wrapped layout of every long table
    gpu = decode_on_gpu(ctx, prt, directions, dialect, width=61)
    cpu = evaluate(prt, directions)
    np.testing.assert_allclose(gpu, cpu, atol=2e-5 * np.abs(cpu).max())


def test_glsl_sh_basis_matches_numpy(ctx):
    source = shader_source("sh_basis.glsl", "glsl330") + """
in vec3 in_dir;
out float v_y[64];
void main() { sh_basis(normalize(in_dir), 8, v_y); }
"""
    program = ctx.program(vertex_shader=source, varyings=["v_y"])
    d = np.random.default_rng(0).normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    vao = ctx.vertex_array(program, [(ctx.buffer(d.astype(np.float32).tobytes()), "3f", "in_dir")])
    out = ctx.buffer(reserve=50 * 64 * 4)
    vao.transform(out, mode=moderngl.POINTS, vertices=50)
    np.testing.assert_allclose(np.frombuffer(out.read(), np.float32).reshape(50, 64), sh_basis(d, 8), atol=2e-5)
