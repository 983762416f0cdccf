"""The reference runtime: renders meshes with the shipped GLSL, headless (moderngl on EGL).

Two vertex stages share one final pass (``sss_surface.frag``): ``prt.vert`` decodes the exported
prt data on the GPU, ``vertex_q.vert`` takes radiance computed per vertex elsewhere (the offline
reference, a baseline). Images are linear float RGB.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .prt_data import PrtData
from .prt_runtime import per_vertex_arrays, upload
from .shaders import shader_source


@dataclass(frozen=True)
class Camera:
    """Attributes
    ----------
    eye : (3,) float
    view_projection : (4, 4) float64
        Row-major matrix taking world points to clip space.
    """

    eye: tuple[float, float, float]
    view_projection: np.ndarray


def fit_camera(positions: np.ndarray, view_dir=(0.3, -0.4, -1.0), fov_degrees: float = 35.0,
               aspect: float = 1.0) -> Camera:
    """A perspective camera looking along `view_dir` that frames the bounding sphere of `positions` (n, 3)."""
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-9)
    forward = np.asarray(view_dir, dtype=np.float64)
    forward /= np.linalg.norm(forward)
    distance = radius / np.sin(np.radians(fov_degrees) / 2.0) * 1.05
    eye = centre - forward * distance
    up = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, true_up, -forward
    view[:3, 3] = -view[:3, :3] @ eye
    near, far = max(distance - radius * 1.5, distance * 1e-3), distance + radius * 1.5
    f = 1.0 / np.tan(np.radians(fov_degrees) / 2.0)
    proj = np.zeros((4, 4))
    proj[0, 0], proj[1, 1] = f / aspect, f
    proj[2, 2], proj[2, 3] = (far + near) / (near - far), 2 * far * near / (near - far)
    proj[3, 2] = -1.0
    return Camera(tuple(eye), proj @ view)


@dataclass(frozen=True)
class RenderLight:
    """Attributes
    ----------
    point : bool
    vector : (3,) float
        World direction towards a directional light, or a point light's world position.
    intensity : float
    mm_per_unit : float
        World units to mm, for a point light's 1/d² falloff.
    """

    point: bool = False
    vector: tuple[float, float, float] = (0.0, 0.0, 1.0)
    intensity: float = 1.0
    mm_per_unit: float = 1.0


class Renderer:
    """A headless GL context with one float render target of `size` (width, height)."""

    def __init__(self, size: tuple[int, int] = (512, 512), dialect: str = "glsl330"):
        import moderngl

        self.ctx = moderngl.create_standalone_context(backend="egl")
        self.size = size
        self.dialect = dialect
        self.fbo = self.ctx.framebuffer(
            color_attachments=[self.ctx.texture(size, 4, dtype="f4")],
            depth_attachment=self.ctx.depth_texture(size),
        )
        self._programs: dict[str, object] = {}

    def _program(self, vertex: str):
        if vertex not in self._programs:
            self._programs[vertex] = self.ctx.program(
                vertex_shader=shader_source(vertex, self.dialect),
                fragment_shader=shader_source("sss_surface.frag", self.dialect))
        return self._programs[vertex]

    def _setup(self, program, model, camera: Camera, light: RenderLight, eta: float, specular: float):
        values = {
            "u_model": np.asarray(model, dtype=np.float32).T.tobytes(),  # GLSL matrices are column-major
            "u_view_projection": np.asarray(camera.view_projection, dtype=np.float32).T.tobytes(),
        }
        for name, raw in values.items():
            program[name].write(raw)
        settings = {"u_point_light": int(light.point), "u_light": tuple(map(float, light.vector)),
                    "u_intensity": float(light.intensity), "u_mm_per_unit": float(light.mm_per_unit),
                    "u_eye": tuple(map(float, camera.eye)), "u_eta": float(eta), "u_specular": float(specular),
                    "u_shininess": 64.0}
        for name, value in settings.items():
            if name in program:
                program[name].value = value

    def _vao(self, program, positions, normals, faces, extra):
        buffers = [(self.ctx.buffer(np.ascontiguousarray(positions, np.float32).tobytes()), "3f", "in_position"),
                   (self.ctx.buffer(np.ascontiguousarray(normals, np.float32).tobytes()), "3f", "in_normal")]
        buffers += [(self.ctx.buffer(np.ascontiguousarray(a).tobytes()), fmt, name) for a, fmt, name in extra]
        index = self.ctx.buffer(np.ascontiguousarray(faces, np.uint32).tobytes())
        return self.ctx.vertex_array(program, [b for b in buffers if b[2] in program], index_buffer=index,
                                     index_element_size=4)

    def _draws(self, items):
        """Programs and vertex arrays for `items`: dicts with ``positions``, ``normals``, ``faces``,
        ``model`` (4, 4), ``eta`` and either ``q`` (n, 3) or ``prt`` (PrtData over the vertices)."""
        draws = []
        for item in items:
            if "prt" in item:
                prt: PrtData = item["prt"]
                program = self._program("prt.vert")
                ref, w = per_vertex_arrays(prt)
                extra = [(ref, "2u2", "in_prt_ref"), (w, "2i2", "in_prt_w")]
            else:
                program = self._program("vertex_q.vert")
                extra = [(np.asarray(item["q"], np.float32), "3f", "in_q")]
            vao = self._vao(program, item["positions"], item["normals"], item["faces"], extra)
            draws.append((program, vao, item))
        return draws

    def render(self, items, camera: Camera, light: RenderLight, specular: float = 0.0):
        """Render `items` (see `_draws`). Returns image (H, W, 3) float32 and coverage (H, W) bool."""
        import moderngl

        draws = self._draws(items)
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        for program, vao, item in draws:
            textures = upload(self.ctx, program, item["prt"]) if "prt" in item else []
            self._setup(program, item["model"], camera, light, item["eta"], specular)
            vao.render(moderngl.TRIANGLES)
            _release(textures)
        _release([vao for _, vao, _ in draws])
        raw = np.frombuffer(self.fbo.read(components=4, dtype="f4"), dtype=np.float32)
        rgba = raw.reshape(self.size[1], self.size[0], 4)[::-1]
        return np.ascontiguousarray(rgba[..., :3]), rgba[..., 3] > 0.5

    def frame_ms(self, items, camera: Camera, light: RenderLight, frames: int = 20) -> float:
        """Median milliseconds per frame (textures and buffers already uploaded, ctx.finish each frame).

        Each draw binds its own textures; scalar uniforms of items sharing a program are those of
        the last item set up, which changes no cost (the images come from `render`)."""
        import moderngl

        draws = self._draws(items)
        kept = [upload(self.ctx, p, item["prt"]) if "prt" in item else [] for p, _, item in draws]
        self.fbo.use()
        self.ctx.enable(moderngl.DEPTH_TEST)
        for p, _, item in draws:
            self._setup(p, item["model"], camera, light, item["eta"], 0.0)
        times = []
        for _ in range(frames + 2):
            t = time.perf_counter()
            self.fbo.clear(0.0, 0.0, 0.0, 0.0)
            for (program, vao, _), textures in zip(draws, kept):
                for unit, texture in enumerate(textures):  # `upload` numbers the units from 0
                    texture.use(unit)
                vao.render(moderngl.TRIANGLES)
            self.ctx.finish()
            times.append(time.perf_counter() - t)
        for textures in kept:
            _release(textures)
        _release([vao for _, vao, _ in draws])
        return 1000.0 * float(np.median(times[2:]))


def _release(objects) -> None:
    for o in objects:
        o.release()
