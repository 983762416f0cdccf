"""Offscreen GL passes of the reference runtimes (kernels, screen): a draw with its samplers and
uniforms, and the conversions they share."""

from __future__ import annotations

import numpy as np

#: How far a shadow lookup moves off the surface, in shadow-map texels (along n and towards the
#: light): enough against self-shadowing of lit surfaces at 1-texel depth quantisation.
SHADOW_OFFSET_TEXELS = 1.5


def shadow_texture(ctx, size: int):
    """A `size`² depth texture for a shadow map, read as depths (compare mode off, nearest)."""
    import moderngl

    texture = ctx.depth_texture((size, size))
    texture.compare_func = ""  # read depths and compare in the shader
    texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return texture


class OwnedObjects:
    """GL objects made for one item's passes, released together (newest first)."""

    def __init__(self):
        self._objects: list = []

    def release(self) -> None:
        for o in reversed(self._objects):
            o.release()
        self._objects = []

    def _keep(self, obj):
        self._objects.append(obj)
        return obj


class Pass:
    """One draw (`vertices` indices from `first`) into a framebuffer with its samplers and
    uniforms, set again every run (passes of several items share the renderer's programs)."""

    def __init__(self, program, vao, framebuffer, samplers: dict, uniforms: dict, vertices: int, first: int = 0,
                 clear: bool = False, mode: int | None = None):
        import moderngl

        self.program, self.vao, self.framebuffer = program, vao, framebuffer
        self.samplers = [(name, tex) for name, tex in samplers.items() if name in program]
        self.uniforms = {name: value for name, value in uniforms.items() if name in program}
        self.vertices, self.first, self.clear = vertices, first, clear
        self.mode = moderngl.TRIANGLES if mode is None else mode

    def run(self) -> None:
        self.framebuffer.use()
        if self.clear:
            self.framebuffer.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        for unit, (name, tex) in enumerate(self.samplers):
            tex.use(unit)
            self.program[name].value = unit
        for name, value in self.uniforms.items():
            self.program[name].value = value
        self.vao.render(self.mode, vertices=self.vertices, first=self.first)


def read_texture(texture, components: int) -> np.ndarray:
    """(texels, components) float32 contents of a float texture, row by row from row 0."""
    return np.frombuffer(texture.read(), np.float32).reshape(-1, components).copy()


def gl_matrix(matrix: np.ndarray) -> tuple:
    """A row-major matrix as a GLSL (column-major) uniform value."""
    return tuple(np.asarray(matrix, dtype=np.float64).T.reshape(-1))


def table_texture(ctx, rows: np.ndarray, dtype: str, width: int, limit: int, what: str = "a table"):
    """Rows (m, components) laid out row-major in a (width, ceil(m / width)) texture; `what`
    names the table in the error when it would exceed GL_MAX_TEXTURE_SIZE `limit`."""
    import moderngl

    if len(rows) == 0:
        rows = np.zeros((1, rows.shape[1]), dtype=rows.dtype)
    m, components = rows.shape
    w = min(width, m)
    h = -(-m // w)
    if w > limit or h > limit:
        raise ValueError(f"{what} ({m} entries) needs {w} x {h} texels, over GL_MAX_TEXTURE_SIZE {limit}")
    data = np.zeros((w * h, components), dtype=rows.dtype)
    data[:m] = rows
    tex = ctx.texture((w, h), components, data.tobytes(), dtype=dtype)
    tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return tex
