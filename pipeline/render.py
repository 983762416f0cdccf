"""The reference runtime: renders meshes with the shipped GLSL, headless (moderngl on EGL).

Six kinds of draw, told apart by the keys of an item (see `Renderer.render`):

- ``prt``: ``prt.vert`` decodes the exported prt data on the GPU per vertex;
- ``q``: ``vertex_q.vert`` takes scattered radiance computed per vertex elsewhere (the offline
  reference, a technique evaluated on the CPU);
- ``kernels``: the kernels technique, whose offscreen passes (`kernels_runtime`: shadow map,
  illumination map, local filter, distribution and global response) run every frame before
  ``kernels_surface.vert``/``.frag`` draw q = B_l(uv) + B_g + B_d;
- ``screen``: the screen technique, whose offscreen passes (`screen_runtime`: shadow map,
  G-buffer from the camera, gather) run every frame before ``screen_surface.frag`` reads B per
  pixel;
- ``lpv``: the lpv technique, whose offscreen passes (`lpv_runtime`: reflective shadow map,
  injection, propagation and accumulation over the flattened grid) run every frame before
  ``lpv_surface.frag`` reads the accumulated intensity per pixel;
- ``albedo``: ``plain.vert``/``plain.frag``, Lambert plus specular without scattering (the
  baseline of frame times).

The scattering draws share one final pass (``sss_surface.frag``, and its kernels variant): exit
Fresnel F_t(η, ω_o) per pixel plus the surface's reflection. Images are linear float RGB.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .kernels_data import KernelsData
from .kernels_runtime import KernelsPasses
from .prt_data import PrtData
from .lpv_data import LpvGrid
from .lpv_runtime import LpvPasses
from .screen_data import ScreenSamples
from .screen_runtime import ScreenPasses, ScreenRuntimeOptions
from .prt_runtime import TABLE_WIDTH, per_vertex_arrays, shader_defines, upload
from .sh import MAX_ORDER as SH_MAX_ORDER
from .shaders import DIALECTS, shader_source

#: Vertex and fragment stage of each kind of draw.
PROGRAMS = {"prt": ("prt.vert", "sss_surface.frag"), "q": ("vertex_q.vert", "sss_surface.frag"),
            "kernels": ("kernels_surface.vert", "kernels_surface.frag"), "screen": ("plain.vert", "screen_surface.frag"),
            "lpv": ("plain.vert", "lpv_surface.frag"), "albedo": ("plain.vert", "plain.frag")}
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


class Renderer:
    """A headless GL context with one float render target.

    Parameters
    ----------
    size : (width, height)
        Image size in pixels, within the GL limits.
    dialect : str
        ``"glsl330"`` or ``"essl300"`` (Mesa accepts ES 3.00 shaders in desktop GL).
    table_width : int
        Width of the wrapped 2-D layout of the prt and kernels tables (`prt_runtime.upload`,
        `kernels_runtime`).
    shadow_size : int
        Side in texels of the kernels draws' shadow maps.
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
            (4, 4) object-to-world, ``eta`` and one of: ``prt`` (`PrtData` over the n vertices,
            q per unit irradiance), ``q`` (n, 3) scattered radiance per vertex (irradiance
            included), ``albedo`` (3,) for the plain shader, ``kernels`` (`KernelsData`) with
            ``uvs`` (n, 2) atlas UVs (glTF convention) and ``vertex_ids`` (n,) int, the welded
            surface vertex of each render vertex (its shadow map holds the item's own triangles),
            ``screen`` (`ScreenSamples`) with ``mm_per_unit`` (mm per object unit) and optionally
            ``screen_runtime`` (`ScreenRuntimeOptions`); its G-buffer and shadow map hold the
            item alone; ``lpv`` (`LpvGrid`, in the item's object frame) with ``lpv_matrices``
            (6, 4, 4), ``lpv_scales`` (S, 3) and optionally ``lpv_steps`` and
            ``lpv_shadow_size`` (`lpv_propagate.LpvOptions`).
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

        Data is uploaded once; each frame clears, runs each kernels and screen draw's offscreen
        passes, binds each draw's textures and uniforms, draws and waits for the GPU
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

    def kernels_passes(self, item: dict, light: RenderLight, illumination: np.ndarray | None = None) -> dict:
        """Run the offscreen passes of a kernels item once and read their results back.

        Parameters
        ----------
        item : dict
            A render item with ``kernels`` (see `render`).
        illumination : (height, width) float, optional
            E to filter and distribute instead of the one the shadow and illumination passes
            render (row 0 = atlas row 0).

        Returns
        -------
        dict
            ``illumination`` (height, width) float32, row 0 = atlas row 0; ``local`` (S, 3) B_l at
            the covered texels; ``e_g`` (n,); ``b_d`` (n, 3); ``b_g`` (n, 3) (`KernelsPasses.read`).
        """
        if _check_item(0, item) != "kernels":
            raise ValueError("render: kernels_passes needs an item with kernels")
        passes = self._kernels_passes(item, light)
        try:
            passes.run(illumination)
            return passes.read()
        finally:
            passes.release()

    def screen_passes(self, item: dict, camera: Camera, light: RenderLight,
                      irradiance: np.ndarray | None = None) -> dict:
        """Run the offscreen passes of a screen item once and read their results back.

        Parameters
        ----------
        item : dict
            A render item with ``screen`` (see `render`).
        irradiance : (H, W) float, optional
            E to gather instead of the one the G-buffer pass lights (row 0 at the top).

        Returns
        -------
        dict
            (H, W, ...) row 0 at the top: ``position``, ``irradiance``, ``normal``, ``covered``,
            ``scattered`` (B), ``share`` (`ScreenPasses.read`).
        """
        if _check_item(0, item) != "screen":
            raise ValueError("render: screen_passes needs an item with screen")
        passes = self._screen_passes(item, camera, light)
        try:
            passes.run(irradiance)
            return passes.read()
        finally:
            passes.release()

    def release(self) -> None:
        """Free the GL context (the renderer is unusable afterwards)."""
        self.ctx.release()

    def _program(self, vertex: str, fragment: str, prelude: str = ""):
        if (vertex, fragment, prelude) not in self._programs:
            self._programs[vertex, fragment, prelude] = self.ctx.program(
                vertex_shader=shader_source(vertex, self.dialect, prelude),
                fragment_shader=shader_source(fragment, self.dialect, prelude))
        return self._programs[vertex, fragment, prelude]

    def _kernels_passes(self, item: dict, light: RenderLight) -> KernelsPasses:
        view_projection, extent, _ = _item_light_camera(item, light)
        return KernelsPasses(self.ctx, self._program, item, light, view_projection, extent, self.fbo,
                             self.table_width, self.shadow_size)

    def lpv_passes(self, item: dict, light: RenderLight, injected: np.ndarray | None = None) -> dict:
        """Run the offscreen passes of an lpv item once and read their grids back.

        Parameters
        ----------
        item : dict
            A render item with ``lpv`` (see `render`).
        injected : (nz, ny, nx, 4) float, optional
            Injected lobes to propagate instead of the shadow map's.

        Returns
        -------
        dict
            ``injected`` (nz, ny, nx, 4) and ``accumulated`` (nz, ny, nx, 3, 4) float32
            (`LpvPasses.read`).
        """
        if _check_item(0, item) != "lpv":
            raise ValueError("render: lpv_passes needs an item with lpv")
        passes = self._lpv_passes(item, light)
        try:
            passes.run(injected)
            return passes.read()
        finally:
            passes.release()

    def _lpv_passes(self, item: dict, light: RenderLight) -> LpvPasses:
        view_projection, extent, tan_half = _item_light_camera(item, light)
        return LpvPasses(self.ctx, self._program, item, light, view_projection, extent, tan_half, self.fbo)

    def _screen_passes(self, item: dict, camera: Camera, light: RenderLight) -> ScreenPasses:
        view_projection, extent, _ = _item_light_camera(item, light)
        return ScreenPasses(self.ctx, self._program, item, light, view_projection, extent, camera, self.size,
                            self.fbo, self.shadow_size)

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
        # one prt variant per SH order and weight layout (see prt_decode.glsl)
        program = self._program(*PROGRAMS[kind], shader_defines(item["prt"]) if kind == "prt" else "")
        textures, extra, passes = [], [], None
        if kind == "prt":
            extra = per_vertex_arrays(item["prt"])
            # `upload` also sets this item's prt uniforms, which `_Draw` snapshots below.
            textures = upload(self.ctx, program, item["prt"], width=self.table_width)
        elif kind == "q":
            extra = [(np.asarray(item["q"], np.float32), "3f", "in_q")]
        elif kind in ("kernels", "screen", "lpv"):
            if kind == "kernels":
                passes = self._kernels_passes(item, light)
                extra = [(np.asarray(item["uvs"], np.float32), "2f", "in_uv"),
                         *passes.surface_attributes(item["vertex_ids"])]
            elif kind == "screen":
                passes = self._screen_passes(item, camera, light)
            else:
                passes = self._lpv_passes(item, light)
                for name, value in passes.surface_uniforms.items():
                    program[name].value = value
            for unit, (name, texture) in enumerate(passes.surface_textures.items()):
                if name in program:
                    program[name].value = unit
                textures.append(texture)
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
    to run first (`KernelsPasses`, `ScreenPasses`: they bind the target framebuffer again)."""

    def __init__(self, program, vao, textures, buffers, passes: KernelsPasses | ScreenPasses | LpvPasses | None = None):
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


def _item_light_camera(item: dict, light: RenderLight) -> tuple[np.ndarray, float, float]:
    """`light_camera` over an item's world-space positions (its shadow map holds the item alone)."""
    model = np.asarray(item["model"], dtype=np.float64)
    world = np.asarray(item["positions"], dtype=np.float64) @ model[:3, :3].T + model[:3, 3]
    return light_camera(world, light)


def _check_item(i: int, item: dict) -> str:
    """The kind of draw of `item` (a key of `PROGRAMS`), after checking its arrays."""
    kinds = [k for k in PROGRAMS if k in item]
    if len(kinds) != 1:
        raise ValueError(f"render: item {i} needs exactly one of {list(PROGRAMS)}, got {sorted(item)}")
    positions = np.asarray(item["positions"])
    n = len(positions)
    faces = np.asarray(item["faces"])
    shapes = {"positions": (n, 3), "normals": (n, 3), "model": (4, 4)}
    shapes.update({"q": {"q": (n, 3)}, "albedo": {"albedo": (3,)}, "kernels": {"uvs": (n, 2)}}.get(kinds[0], {}))
    for name, shape in shapes.items():
        a = np.asarray(item[name])
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise ValueError(f"render: item {i}: {name} must be finite with shape {shape}, got {a.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not len(faces) or not np.issubdtype(faces.dtype, np.integer) or (
            faces.min() < 0 or faces.max() >= n):
        raise ValueError(f"render: item {i}: faces must be (m, 3) integer indices into {n} vertices, m >= 1")
    if not np.isfinite(item["eta"]) or not item["eta"] > 0:
        raise ValueError(f"render: item {i}: eta must be positive, got {item['eta']}")
    if abs(np.linalg.det(np.asarray(item["model"], dtype=np.float64)[:3, :3])) < 1e-30:
        raise ValueError(f"render: item {i}: model matrix is singular")
    if kinds[0] == "prt" and (not isinstance(item["prt"], PrtData) or item["prt"].vertex_count != n
                              or not 0 <= item["prt"].sh_order <= SH_MAX_ORDER):
        raise ValueError(f"render: item {i}: prt must be PrtData over the item's {n} vertices, SH order <= {SH_MAX_ORDER}")
    if kinds[0] == "kernels":
        _check_kernels(i, item, n)
    if kinds[0] == "screen":
        _check_screen(i, item)
    if kinds[0] == "lpv":
        _check_lpv(i, item)
    return kinds[0]


def _check_lpv(i: int, item: dict) -> None:
    """The grid, matrices and scales of lpv item `i`."""
    grid = item["lpv"]
    if not isinstance(grid, LpvGrid):
        raise ValueError(f"render: item {i}: lpv must be LpvGrid, got {type(grid).__name__}")
    try:
        grid.check()
    except ValueError as error:
        raise ValueError(f"render: item {i}: {error}") from None
    matrices, scales = np.asarray(item.get("lpv_matrices")), np.asarray(item.get("lpv_scales"))
    if matrices.shape != (6, 4, 4) or scales.ndim != 2 or scales.shape[1] != 3 or not len(scales):
        raise ValueError(f"render: item {i}: lpv needs lpv_matrices (6, 4, 4) and lpv_scales (S, 3), got "
                         f"{matrices.shape} and {scales.shape}")


def _check_screen(i: int, item: dict) -> None:
    """The sample tables, scale and runtime options of screen item `i`."""
    if not isinstance(item["screen"], ScreenSamples):
        raise ValueError(f"render: item {i}: screen must be ScreenSamples, got {type(item['screen']).__name__}")
    try:
        item["screen"].check()
    except ValueError as error:
        raise ValueError(f"render: item {i}: {error}") from None
    mm = item.get("mm_per_unit")
    if not isinstance(mm, (int, float)) or not (np.isfinite(mm) and mm > 0):
        raise ValueError(f"render: item {i}: a screen item needs mm_per_unit > 0 (mm per object unit), got {mm!r}")
    if not isinstance(item.get("screen_runtime", ScreenRuntimeOptions()), ScreenRuntimeOptions):
        raise ValueError(f"render: item {i}: screen_runtime must be ScreenRuntimeOptions")


def _check_kernels(i: int, item: dict, n: int) -> None:
    """The kernels data of item `i` (n render vertices) and its map to the welded vertices."""
    data = item["kernels"]
    if not isinstance(data, KernelsData):
        raise ValueError(f"render: item {i}: kernels must be KernelsData, got {type(data).__name__}")
    try:
        data.check()
    except ValueError as error:
        raise ValueError(f"render: item {i}: {error}") from None
    ids = np.asarray(item["vertex_ids"])
    count = data.surface_vertex_count
    if ids.shape != (n,) or not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0 or ids.max() >= count:
        raise ValueError(f"render: item {i}: vertex_ids must be ({n},) integers in 0..{count - 1}")
    if not np.all(np.isin(data.border_vertices, ids)):
        raise ValueError(f"render: item {i}: border texels use welded vertices no render vertex maps to")
