"""The headless GL stack the reference renderer relies on: moderngl on EGL (Mesa llvmpipe here)."""

import moderngl
import numpy as np
import pytest


def test_egl_context_rasterises_a_triangle():
    try:
        ctx = moderngl.create_standalone_context(backend="egl")
    except Exception as e:  # noqa: BLE001 - the message says what is missing
        pytest.fail(f"no EGL context ({e}); install Mesa's EGL packages (bash .ci/setup)")
    prog = ctx.program(
        vertex_shader="#version 330\nin vec2 p; void main() { gl_Position = vec4(p, 0.0, 1.0); }",
        fragment_shader="#version 330\nout vec4 c; void main() { c = vec4(1.0, 0.5, 0.25, 1.0); }",
    )
    vbo = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1], dtype="f4").tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "2f", "p")])
    fbo = ctx.simple_framebuffer((8, 8))
    fbo.use()
    fbo.clear(0.0, 0.0, 0.0, 1.0)
    vao.render()
    img = np.frombuffer(fbo.read(components=4), dtype=np.uint8).reshape(8, 8, 4)
    covered = np.all(img[..., :3] == [255, 128, 64], axis=-1).sum()
    # The lower-left half-square: 8·8/2 pixels plus the 4 centres on the diagonal rule edge, give or take.
    assert 28 <= covered <= 36
    assert np.all(img[7, 7, :3] == 0) or np.all(img[0, 7, :3] == 0)
    ctx.release()
