"""The reference runtime: renders meshes with the shipped GLSL, headless (moderngl on EGL).

An item's kind of draw is the one key of `draw_kinds` it holds (see `Renderer.render`). The
renderer knows two:

- ``q``: ``vertex_q.vert`` takes scattered radiance computed per vertex elsewhere (the offline
  reference, a technique evaluated on the CPU);
- ``albedo``: ``plain.vert``/``plain.frag``, Lambert plus specular without scattering (the
  baseline of frame times);

and each technique with a runtime of its own brings its kind, keyed by its name (a `DrawKind` in
its ``runtime.py``, the registry's ``Technique.draw``): ``prt`` decodes the exported data per
vertex in ``prt.vert``; ``kernels``, ``screen`` and ``lpv`` run offscreen passes every frame
before their final draw.

The scattering draws share one final pass (``sss_surface.frag``, and its kernels variant): exit
Fresnel F_t(η, ω_o) per pixel plus the surface's reflection. Images are linear float RGB.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from sssbake.pipeline.render.shaders import DIALECTS, shader_source

#: Width of the wrapped 2-D layout of long tables (GL guarantees 4096-texel-wide textures... and
#: far more on desktop; 4096 keeps ES 3.00's minimum of 2048 rows enough for 8M entries).
TABLE_WIDTH = 4096
#: World direction towards the light verify and the planner's pilot use unless told otherwise.
DEFAULT_LIGHT = (0.4, 0.8, 0.45)
#: Largest tan(half field of view) of a point light's shadow map (80°): a light inside or at the
#: item's bounding sphere sees only this cone, points outside it count as lit.
MAX_SHADOW_TAN = float(np.tan(np.radians(80.0)))


@dataclass(frozen=True, eq=False)
class Camera:
    """Attributes
    ----------
    eye : (3,) float
        World position of the eye.
    view_projection : (4, 4) float64
        Row-major matrix taking world points to clip space.
    """

    eye: tuple[float, float, float]
    view_projection: np.ndarray


def fit_camera(positions: np.ndarray, view_dir=(0.3, -0.4, -1.0), fov_degrees: float = 35.0,
               aspect: float = 1.0) -> Camera:
    """A perspective camera looking along `view_dir` that frames the bounding sphere of `positions`.

    Parameters
    ----------
    positions : (n, 3) float
        World points to frame (n >= 1).
    view_dir : (3,) float
        Viewing direction (need not be unit).
    fov_degrees : float
        Vertical field of view, in (0, 180).
    aspect : float
        Width / height of the image.
    """
    positions = np.asarray(positions, dtype=np.float64)
    forward = np.asarray(view_dir, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or not len(positions) or not np.all(np.isfinite(positions)):
        raise ValueError(f"render: camera needs finite (n, 3) positions, n >= 1, got shape {positions.shape}")
    if forward.shape != (3,) or not np.all(np.isfinite(forward)) or not np.linalg.norm(forward) > 0:
        raise ValueError(f"render: view direction must be three finite numbers, not all zero, got {view_dir}")
    if not 0.0 < fov_degrees < 180.0 or not aspect > 0.0 or not np.isfinite(aspect):
        raise ValueError(f"render: need 0 < fov < 180 degrees and aspect > 0, got {fov_degrees}, {aspect}")
    centre, radius = _bounding_sphere(positions)
    forward /= np.linalg.norm(forward)
    tan_half = np.tan(np.radians(fov_degrees) / 2.0)
    # The narrower of the two fields of view must hold the sphere.
    half = min(np.arctan(tan_half), np.arctan(tan_half * aspect))
    distance = radius / np.sin(half) * 1.05
    eye = centre - forward * distance
    near, far = max(distance - radius * 1.5, distance * 1e-3), distance + radius * 1.5
    return Camera(tuple(eye), _perspective(tan_half, aspect, near, far) @ _look_at(eye, forward))


def light_camera(positions: np.ndarray, light: RenderLight) -> tuple[np.ndarray, float, float]:
    """The view-projection of a shadow map of `light` over the bounding sphere of `positions`.

    Directional light: orthographic along the light. Point light: perspective from the light
    towards the sphere (a cone of at most `MAX_SHADOW_TAN` when the light is inside or near it).

    Parameters
    ----------
    positions : (n, 3) float
        World points the map must hold (n >= 1, finite).

    Returns
    -------
    view_projection : (4, 4) float64
        Row-major, world to clip space.
    extent : float
        World width the map spans at the sphere's centre (one shadow texel is extent / size).
    tan_half : float
        A point light's tan(half field of view), 0 for a directional light.
    """
    centre, radius = _bounding_sphere(np.asarray(positions, dtype=np.float64))
    radius *= 1.01  # points on the sphere stay inside the frustum despite rounding
    vector = np.asarray(light.vector, dtype=np.float64)
    if not light.point:
        forward = -vector / np.linalg.norm(vector)
        view = _look_at(centre - 2.0 * radius * forward, forward)
        ortho = np.diag([1.0 / radius, 1.0 / radius, -1.0 / radius, 1.0])
        ortho[2, 3] = -2.0  # depth: distances radius .. 3 radius to -1 .. 1
        return ortho @ view, 2.0 * radius, 0.0
    offset = centre - vector
    distance = float(np.linalg.norm(offset))
    forward = offset / distance if distance > 0 else np.array([0.0, 0.0, -1.0])
    gap = distance * distance - radius * radius
    tan_half = min(radius / np.sqrt(gap), MAX_SHADOW_TAN) if gap > 0 else MAX_SHADOW_TAN
    near, far = max(distance - radius, 1e-3 * radius), distance + radius
    projection = _perspective(tan_half, 1.0, near, far) @ _look_at(vector, forward)
    return projection, 2.0 * max(distance, radius) * tan_half, float(tan_half)


def _bounding_sphere(positions: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius (> 0) of the sphere around the bounding box of (n, 3) `positions`."""
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    return 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-9)


def _look_at(eye: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """(4, 4) view matrix of an eye looking along unit `forward`, y up unless forward is near it."""
    up = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, true_up, -forward
    view[:3, 3] = -view[:3, :3] @ eye
    return view


def _perspective(tan_half: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4, 4) GL perspective projection of vertical half-angle tangent `tan_half`."""
    f = 1.0 / tan_half
    proj = np.zeros((4, 4))
    proj[0, 0], proj[1, 1] = f / aspect, f
    proj[2, 2], proj[2, 3] = (far + near) / (near - far), 2 * far * near / (near - far)
    proj[3, 2] = -1.0
    return proj


@dataclass(frozen=True)
class RenderLight:
    """Attributes
    ----------
    point : bool
    vector : (3,) float
        World direction towards a directional light (normalised by the shaders), or a point
        light's world position.
    intensity : float
        Irradiance of a directional light; a point light's intensity (irradiance · mm²).
    mm_per_unit : float
        World units to mm, for a point light's 1/d² falloff.
    """

    point: bool = False
    vector: tuple[float, float, float] = (0.0, 0.0, 1.0)
    intensity: float = 1.0
    mm_per_unit: float = 1.0

    def __post_init__(self):
        v = np.asarray(self.vector, dtype=np.float64)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or (not self.point and not np.linalg.norm(v) > 0):
            raise ValueError(f"render: light vector must be three finite numbers (non-zero direction), got {self.vector}")
        if not (np.isfinite(self.intensity) and self.intensity >= 0 and np.isfinite(self.mm_per_unit)
                and self.mm_per_unit > 0):
            raise ValueError(f"render: light needs intensity >= 0 and mm_per_unit > 0, got {self.intensity}, "
                             f"{self.mm_per_unit}")


class DrawKind:
    """How `Renderer` draws the items of one kind (module docstring): each technique with a runtime
    of its own subclasses it in its ``runtime.py`` (one instance, its ``Technique.draw``).

    Class attributes
    ----------------
    program : (str, str)
        Vertex and fragment stage of the final draw.
    """

    program: ClassVar[tuple[str, str]]

    def check(self, i: int, item: dict) -> None:
        """Raise ValueError (``render: item {i}: ...``) when item `i`, whose geometry is checked,
        cannot be drawn."""

    def defines(self, item: dict) -> str:
        """The ``#define`` lines of the final draw's program variant for `item` (none by default)."""
        return ""

    def passes(self, renderer: Renderer, item: dict, camera: Camera | None, light: RenderLight):
        """The item's offscreen passes, run before each final draw: an object with ``run(given=None)``,
        ``read() -> dict``, ``release()`` and ``surface_textures`` (the final draw's samplers by
        uniform name); None (the default) for a draw without any."""
        return None

    def setup(self, renderer: Renderer, program, item: dict, passes) -> tuple[list, list]:
        """The final draw's extra vertex attributes, ``(array (n, c), moderngl format, shader input)``
        each, and its textures (unit i the i-th), after setting the `program` uniforms they need.
        By default: none, and the passes' ``surface_textures``."""
        textures = []
        if passes is not None:
            for unit, (name, texture) in enumerate(passes.surface_textures.items()):
                if name in program:
                    program[name].value = unit
                textures.append(texture)
        return [], textures


class _PerVertexQ(DrawKind):
    """``q``: (n, 3) scattered radiance per vertex, irradiance included."""

    program = ("vertex_q.vert", "sss_surface.frag")

    def check(self, i: int, item: dict) -> None:
        check_array(i, item, "q", (len(item["positions"]), 3))

    def setup(self, renderer: Renderer, program, item: dict, passes) -> tuple[list, list]:
        return [(np.asarray(item["q"], np.float32), "3f", "in_q")], []


class _Plain(DrawKind):
    """``albedo``: (3,) the plain shader's Lambert albedo."""

    program = ("plain.vert", "plain.frag")

    def check(self, i: int, item: dict) -> None:
        check_array(i, item, "albedo", (3,))


@functools.cache
def draw_kinds() -> dict[str, DrawKind]:
    """Every kind of draw by the item key that selects it: the techniques' (registry order), then
    ``q`` and ``albedo``."""
    # The one sanctioned upward late binding: the registry (techniques layer, above this one)
    # lists the techniques' draws; importing it on first use keeps this module below them.
    from sssbake.pipeline.techniques.registry import TECHNIQUES

    return {**{t.name: t.draw for t in TECHNIQUES if t.draw is not None}, "q": _PerVertexQ(), "albedo": _Plain()}


def check_data(i: int, item: dict, name: str, kind: type) -> None:
    """ValueError unless item `i`'s `name` is a `kind` whose own ``check()`` passes."""
    data = item[name]
    if not isinstance(data, kind):
        raise ValueError(f"render: item {i}: {name} must be {kind.__name__}, got {type(data).__name__}")
    try:
        data.check()
    except ValueError as error:
        raise ValueError(f"render: item {i}: {error}") from None


def check_array(i: int, item: dict, name: str, shape: tuple[int, ...]) -> None:
    """ValueError unless item `i`'s `name` is finite with `shape`."""
    a = np.asarray(item[name])
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ValueError(f"render: item {i}: {name} must be finite with shape {shape}, got {a.shape}")


class Renderer:
    """A headless GL context with one float render target.

    Parameters
    ----------
    size : (width, height)
        Image size in pixels, within the GL limits.
    dialect : str
        ``"glsl330"`` or ``"essl300"`` (Mesa accepts ES 3.00 shaders in desktop GL).
    table_width : int
        Width of the wrapped 2-D layout of the techniques' long tables.
    shadow_size : int
        Side in texels of the techniques' shadow maps (those that take the renderer's).
    """

    def __init__(self, size: tuple[int, int] = (512, 512), dialect: str = "glsl330", table_width: int = TABLE_WIDTH,
                 shadow_size: int = 2048):
        import moderngl

        if dialect not in DIALECTS:
            raise ValueError(f"render: dialect must be one of {sorted(DIALECTS)}, got {dialect!r}")
        self.ctx = moderngl.create_standalone_context(backend="egl")
        limit = min(self.ctx.info["GL_MAX_TEXTURE_SIZE"], self.ctx.info["GL_MAX_RENDERBUFFER_SIZE"],
                    *self.ctx.info["GL_MAX_VIEWPORT_DIMS"])
        width, height = (int(s) for s in size)
        if not (0 < width <= limit and 0 < height <= limit):
            self.ctx.release()
            raise ValueError(f"render: image size {size} outside 1..{limit} (this GL's limit)")
        if not 0 < shadow_size <= self.ctx.info["GL_MAX_TEXTURE_SIZE"]:
            self.ctx.release()
            raise ValueError(f"render: shadow map size {shadow_size} outside 1..{self.ctx.info['GL_MAX_TEXTURE_SIZE']}")
        self.size = (width, height)
        self.dialect = dialect
        self.table_width = table_width
        self.shadow_size = int(shadow_size)
        self.fbo = self.ctx.framebuffer(
            color_attachments=[self.ctx.texture(self.size, 4, dtype="f4")],
            depth_attachment=self.ctx.depth_texture(self.size),
        )
        self._programs: dict[tuple[str, str, str], object] = {}

    def render(self, items, camera: Camera, light: RenderLight, specular: float = 0.0, shininess: float = 64.0,
               diffuse=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Draw `items` with depth testing.

        Parameters
        ----------
        items : list of dict
            Each with ``positions`` (n, 3), ``normals`` (n, 3), ``faces`` (m, 3) int, ``model``
            (4, 4) object-to-world, ``eta`` and exactly one key of `draw_kinds`, with what its kind
            reads: ``q`` (n, 3) scattered radiance per vertex (irradiance included); ``albedo``
            (3,) for the plain shader; a technique's name with what its runtime's `DrawKind`
            documents (e.g. ``prt``: `PrtData` over the n vertices).
        specular : float
            Weight of the surface's specular reflection (Fresnel reflectance 1 - F_t times a
            normalised Blinn-Phong lobe of exponent `shininess`).
        diffuse : (3,) float
            Albedo of an extra Lambertian surface term on the scattering draws (default none).

        Returns
        -------
        image : (H, W, 3) float32
            Linear radiance, row 0 at the top.
        coverage : (H, W) bool
        """
        import moderngl

        draws = self._prepare(items, camera, light, specular, shininess, diffuse)
        try:
            self.fbo.use()
            self.ctx.enable(moderngl.DEPTH_TEST)
            self.fbo.clear(0.0, 0.0, 0.0, 0.0)
            for draw in draws:
                draw.run()
            raw = np.frombuffer(self.fbo.read(components=4, dtype="f4"), dtype=np.float32)
        finally:
            for draw in draws:
                draw.release()
        rgba = raw.reshape(self.size[1], self.size[0], 4)[::-1]
        if not np.all(np.isfinite(rgba)):
            raise ValueError("render: the image has non-finite values (inputs too large for float32?)")
        return np.ascontiguousarray(rgba[..., :3]), rgba[..., 3] > 0.5

    def frame_ms(self, items, camera: Camera, light: RenderLight, frames: int = 20, specular: float = 0.0) -> float:
        """Median milliseconds per frame of drawing `items` (see `render`).

        Data is uploaded once; each frame clears, runs each draw's offscreen passes, binds each
        draw's textures and uniforms, draws and waits for the GPU
        (``ctx.finish``). Two warm-up frames are not counted.
        """
        import moderngl

        if frames < 1:
            raise ValueError(f"render: frames must be >= 1, got {frames}")
        draws = self._prepare(items, camera, light, specular, 64.0, (0.0, 0.0, 0.0))
        times = []
        try:
            self.fbo.use()
            self.ctx.enable(moderngl.DEPTH_TEST)
            for _ in range(frames + 2):
                t = time.perf_counter()
                self.fbo.clear(0.0, 0.0, 0.0, 0.0)
                for draw in draws:
                    draw.run()
                self.ctx.finish()
                times.append(time.perf_counter() - t)
        finally:
            for draw in draws:
                draw.release()
        return 1000.0 * float(np.median(times[2:]))

    def passes(self, item: dict, light: RenderLight, camera: Camera | None = None, given: np.ndarray | None = None
               ) -> dict:
        """Run the offscreen passes of `item` once and read their results back.

        Parameters
        ----------
        item : dict
            A render item whose kind has offscreen passes (``kernels``, ``screen``, ``lpv``; see
            `render`).
        camera : Camera, optional
            The image's (screen's G-buffer is the camera's; the others need none).
        given : ndarray, optional
            What to run the later passes on instead of what the first ones render: kernels'
            illumination E (height, width), row 0 = atlas row 0; screen's irradiance E (H, W),
            row 0 at the top; lpv's injected lobes (nz, ny, nx, 4).

        Returns
        -------
        dict
            The passes' ``read()``: kernels ``illumination`` (height, width) float32, ``local``
            (S, 3) B_l at the covered texels, ``e_g`` (n,), ``b_d`` (n, 3), ``b_g`` (n, 3)
            (`KernelsPasses.read`); screen (H, W, ...) row 0 at the top: ``position``,
            ``irradiance``, ``normal``, ``covered``, ``scattered`` (B), ``share``
            (`ScreenPasses.read`); lpv ``injected`` (nz, ny, nx, 4) and ``accumulated``
            (nz, ny, nx, 3, 4) float32 (`LpvPasses.read`).
        """
        kind = _check_item(0, item)
        passes = draw_kinds()[kind].passes(self, item, camera, light)
        if passes is None:
            raise ValueError(f"render: a {kind} item has no offscreen passes")
        try:
            passes.run(given)
            return passes.read()
        finally:
            passes.release()

    def release(self) -> None:
        """Free the GL context (the renderer is unusable afterwards)."""
        self.ctx.release()

    def program(self, vertex: str, fragment: str, prelude: str = ""):
        """The linked program of shader files `vertex` and `fragment` after `prelude` (cached)."""
        if (vertex, fragment, prelude) not in self._programs:
            self._programs[vertex, fragment, prelude] = self.ctx.program(
                vertex_shader=shader_source(vertex, self.dialect, prelude),
                fragment_shader=shader_source(fragment, self.dialect, prelude))
        return self._programs[vertex, fragment, prelude]

    def _prepare(self, items, camera, light, specular, shininess, diffuse) -> list[_Draw]:
        if not len(items):
            raise ValueError("render: nothing to draw (no items)")
        draws = []
        try:
            for i, item in enumerate(items):
                kind = _check_item(i, item)
                draws.append(self._draw(kind, item, camera, light, specular, shininess, diffuse))
        except Exception:
            for draw in draws:
                draw.release()
            raise
        return draws

    def _draw(self, kind, item, camera, light, specular, shininess, diffuse) -> _Draw:
        draw = draw_kinds()[kind]
        program = self.program(*draw.program, draw.defines(item))
        passes = draw.passes(self, item, camera, light)
        try:
            extra, textures = draw.setup(self, program, item, passes)
        except Exception:
            if passes is not None:
                passes.release()
            raise
        linear = np.asarray(item["model"], dtype=np.float64)[:3, :3]
        to_object = np.linalg.inv(linear)
        matrices = {"u_model": item["model"], "u_view_projection": camera.view_projection,
                    "u_normal_matrix": to_object.T, "u_world_to_object": to_object, "u_object_normal": linear.T}
        for name, matrix in matrices.items():
            if name in program:  # GLSL matrices are column-major
                program[name].write(np.asarray(matrix, dtype=np.float32).T.tobytes())
        albedo = item.get("albedo", diffuse)
        settings = {"u_point_light": int(light.point), "u_light": tuple(map(float, light.vector)),
                    "u_intensity": float(light.intensity), "u_mm_per_unit": float(light.mm_per_unit),
                    "u_eye": tuple(map(float, camera.eye)), "u_eta": float(item["eta"]),
                    "u_specular": float(specular), "u_shininess": float(shininess),
                    "u_diffuse": tuple(map(float, albedo))}
        for name, value in settings.items():
            if name in program:
                program[name].value = value
        arrays = [(item["positions"], "3f", "in_position"), (item["normals"], "3f", "in_normal")] + extra
        try:
            buffers = [self.ctx.buffer(np.ascontiguousarray(a, np.float32 if f.endswith("f") else None).tobytes())
                       for a, f, _ in arrays]
            buffers.append(self.ctx.buffer(np.ascontiguousarray(item["faces"], np.uint32).tobytes()))
            content = [(b, f, name) for b, (_, f, name) in zip(buffers, arrays) if name in program]
            vao = self.ctx.vertex_array(program, content, index_buffer=buffers[-1], index_element_size=4)
        except Exception:
            if passes is not None:
                passes.release()
            raise
        return _Draw(program, vao, textures, buffers, passes)


class _Draw:
    """One item ready to draw: its vertex array, textures and the uniform values it was set up with
    (several items may share a program, so each draw restores its own), and the offscreen passes
    to run first (`DrawKind.passes`: they bind the target framebuffer again)."""

    def __init__(self, program, vao, textures, buffers, passes=None):
        import moderngl

        self.program, self.vao, self.textures, self.buffers, self.passes = program, vao, textures, buffers, passes
        self.uniforms = {name: program[name].read() for name in program
                         if isinstance(program[name], moderngl.Uniform)}

    def run(self) -> None:
        import moderngl

        if self.passes is not None:
            self.passes.run()
        for name, raw in self.uniforms.items():
            self.program[name].write(raw)
        for unit, texture in enumerate(self.textures):  # `upload` numbers the units from 0
            texture.use(unit)
        self.vao.render(moderngl.TRIANGLES)

    def release(self) -> None:
        owned = self.textures if self.passes is None else [self.passes]  # the passes own their textures
        for o in [self.vao, *owned, *self.buffers]:
            o.release()


def item_light_camera(item: dict, light: RenderLight) -> tuple[np.ndarray, float, float]:
    """`light_camera` over an item's world-space positions (its shadow map holds the item alone)."""
    model = np.asarray(item["model"], dtype=np.float64)
    world = np.asarray(item["positions"], dtype=np.float64) @ model[:3, :3].T + model[:3, 3]
    return light_camera(world, light)


def _check_item(i: int, item: dict) -> str:
    """The kind of draw of `item` (a key of `draw_kinds`), after checking its arrays."""
    kinds = draw_kinds()
    keys = [k for k in kinds if k in item]
    if len(keys) != 1:
        raise ValueError(f"render: item {i} needs exactly one of {list(kinds)}, got {sorted(item)}")
    n = len(np.asarray(item["positions"]))
    for name, shape in {"positions": (n, 3), "normals": (n, 3), "model": (4, 4)}.items():
        check_array(i, item, name, shape)
    faces = np.asarray(item["faces"])
    if faces.ndim != 2 or faces.shape[1] != 3 or not len(faces) or not np.issubdtype(faces.dtype, np.integer) or (
            faces.min() < 0 or faces.max() >= n):
        raise ValueError(f"render: item {i}: faces must be (m, 3) integer indices into {n} vertices, m >= 1")
    if not np.isfinite(item["eta"]) or not item["eta"] > 0:
        raise ValueError(f"render: item {i}: eta must be positive, got {item['eta']}")
    if abs(np.linalg.det(np.asarray(item["model"], dtype=np.float64)[:3, :3])) < 1e-30:
        raise ValueError(f"render: item {i}: model matrix is singular")
    kinds[keys[0]].check(i, item)
    return keys[0]
