"""The lpv technique (Børlum et al. 2011) on the GPU with moderngl: an `LpvGrid` uploaded as three
material textures and the per-frame passes before `render`'s final draw (``plain.vert`` /
``lpv_surface.frag``), fragment and point passes only, so GLSL 3.30 and ES 3.00 run it (ES needs
float render targets and, for the injection's additive blending, float blending):

1. reflective shadow map from the light: object-space point and normal per texel
   (``lpv_rsm.vert`` / ``.frag``);
2. injection: one point per texel into its cell of the flattened grid, the lobes summed by
   additive blending (``lpv_inject.vert`` / ``.frag``);
3. per step, propagation over the flattened grid (``fullscreen.vert``, ``lpv_propagate.frag``)
   and accumulation (``lpv_accumulate.frag``), ping-ponging two sets of three RGBA32F textures
   (one per colour channel, the four SH coefficients in RGBA).

The grid's nx × ny × nz cells are one 2-D texture nx wide and ny nz tall (``lpv_grid.glsl``).
`lpv_propagate` is the numpy reference of the same steps. `LPV_DRAW` is the renderer's ``lpv`` draw.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.render.gl_passes import OwnedObjects, Pass, gl_matrix, read_texture
from sssbake.pipeline.render.renderer import DrawKind, check_data, item_light_camera
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.matrices import DIRECTIONS
from sssbake.pipeline.techniques.lpv.propagate import LPV_DEFAULTS

#: Vertex and fragment stage of each offscreen pass.
PASS_PROGRAMS = {"rsm": ("lpv_rsm.vert", "lpv_rsm.frag"), "inject": ("lpv_inject.vert", "lpv_inject.frag"),
                 "propagate": ("fullscreen.vert", "lpv_propagate.frag"),
                 "accumulate": ("fullscreen.vert", "lpv_accumulate.frag")}
CHANNELS = ("red", "green", "blue")


class LpvPasses(OwnedObjects):
    """One lpv item's GL objects and passes 1-3 (module docstring).

    Parameters
    ----------
    ctx, program, light, light_view_projection, shadow_extent, target
        As `kernels_runtime.KernelsPasses`'.
    item : dict
        A checked render item of kind ``"lpv"`` (see `render.Renderer.render`).
    tan_half : float
        A point light's map's tan(half field of view) (`render.light_camera`).
    """

    def __init__(self, ctx, program, item: dict, light, light_view_projection: np.ndarray, shadow_extent: float,
                 tan_half: float, target):
        import moderngl

        super().__init__()
        self.ctx, self.target = ctx, target
        grid: LpvGrid = item["lpv"]
        self.grid = grid
        steps = int(item.get("lpv_steps", LPV_DEFAULTS.steps))
        size = int(item.get("lpv_shadow_size", LPV_DEFAULTS.shadow_size))
        scales = np.asarray(item["lpv_scales"], dtype=np.float64)
        nx, ny, nz = grid.shape
        self.flat = (nx, ny * nz)
        limit = ctx.info["GL_MAX_TEXTURE_SIZE"]
        if max(self.flat) > limit or size > limit:
            raise ValueError(f"lpv runtime: a {nx} x {ny} x {nz} grid flattens to {self.flat[0]} x {self.flat[1]} "
                             f"texels; with a {size}² shadow map, over GL_MAX_TEXTURE_SIZE {limit}")
        if not 1 <= steps <= len(scales):
            raise ValueError(f"lpv runtime: {steps} steps, but the render scale is tabulated for 1..{len(scales)}")
        try:
            def texture(data=None, shape=None):
                tex = self._keep(ctx.texture(shape or self.flat, 4, None if data is None else
                                             np.ascontiguousarray(data, np.float32).tobytes(), dtype="f4"))
                tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
                return tex

            def rgba(rgb, alpha=None):
                out = np.zeros((nz, ny, nx, 4), np.float32)
                out[..., :3] = rgb
                if alpha is not None:
                    out[..., 3] = alpha
                return out

            material = {"u_medium": texture(rgba(grid.sigma_t, grid.occupancy)),
                        "u_albedo": texture(rgba(grid.albedo)), "u_phase": texture(rgba(grid.g))}
            self.material = material
            grid_uniforms = {"u_grid": (nx, ny, nz), "u_cell_mm": grid.cell_mm}
            injection = texture()
            current = [[texture() for _ in CHANNELS] for _ in range(2)]
            sums = [[texture() for _ in CHANNELS] for _ in range(2)]
            points, normals = texture(shape=(size, size)), texture(shape=(size, size))

            model = np.asarray(item["model"], dtype=np.float64)
            linear = model[:3, :3]
            buffers = [self._keep(ctx.buffer(np.ascontiguousarray(item[key], np.float32).tobytes()))
                       for key in ("positions", "normals")]
            indices = self._keep(ctx.buffer(np.ascontiguousarray(item["faces"], np.uint32).tobytes()))
            rsm = program(*PASS_PROGRAMS["rsm"])
            rsm_vao = self._keep(ctx.vertex_array(
                rsm, [(b, "3f", n) for b, n in zip(buffers, ("in_position", "in_normal")) if n in rsm],
                index_buffer=indices, index_element_size=4))
            passes = [Pass(rsm, rsm_vao, self._keep(ctx.framebuffer(
                color_attachments=[points, normals], depth_attachment=self._keep(ctx.depth_renderbuffer((size, size))))),
                {}, {"u_model": gl_matrix(model), "u_view_projection": gl_matrix(light_view_projection)},
                3 * len(item["faces"]), clear=True)]

            # The light in the object's frame (similarity transforms), mm per world unit for the flux.
            mm_per_world = grid.mm_per_unit / abs(np.linalg.det(linear)) ** (1.0 / 3.0)
            if light.point:
                towards = np.linalg.solve(linear, np.asarray(light.vector, dtype=np.float64) - model[:3, 3])
            else:
                towards = np.linalg.solve(linear, np.asarray(light.vector, dtype=np.float64))
                towards /= np.linalg.norm(towards)
            inject = program(*PASS_PROGRAMS["inject"])
            self._inject = Pass(inject, self._keep(ctx.vertex_array(inject, [])),
                                self._keep(ctx.framebuffer(color_attachments=[injection])),
                                {"u_points": points, "u_normals": normals},
                                {**grid_uniforms, "u_size": size, "u_point_light": int(light.point),
                                 "u_light": tuple(map(float, towards)), "u_intensity": float(light.intensity),
                                 "u_texel_mm2": float((shadow_extent / size * mm_per_world) ** 2),
                                 "u_tan_half": float(tan_half), "u_eta": float(grid.eta),
                                 "u_origin": tuple(map(float, grid.origin)), "u_cell": float(grid.cell)},
                                size * size, clear=True, mode=moderngl.POINTS)
            self._first = passes

            propagate = program(*PASS_PROGRAMS["propagate"])
            accumulate = program(*PASS_PROGRAMS["accumulate"])
            screen = {p: self._keep(ctx.vertex_array(p, [])) for p in (propagate, accumulate)}
            matrices = np.asarray(item["lpv_matrices"], dtype=np.float64)
            transport = {**grid_uniforms, "u_matrices": [gl_matrix(m) for m in matrices],
                         "u_directions": [tuple(int(v) for v in d) for d in DIRECTIONS]}

            def target_of(textures):
                return self._keep(ctx.framebuffer(color_attachments=textures))

            def named(prefix, textures):
                return {f"{prefix}{c}": t for c, t in zip(CHANNELS, textures)}

            self._steps = [Pass(accumulate, screen[accumulate], target_of(sums[0]),
                                {**named("u_sum_", sums[1]), **named("u_", [injection] * 3)}, {}, 3)]
            self._clear = target_of(sums[1])
            for s in range(steps):
                src, dst = current[s % 2] if s else [injection] * 3, current[(s + 1) % 2]
                self._steps.append(Pass(propagate, screen[propagate], target_of(dst),
                                        {**material, **named("u_", src)}, transport, 3))
                self._steps.append(Pass(accumulate, screen[accumulate], target_of(sums[(s + 1) % 2]),
                                        {**named("u_sum_", sums[s % 2]), **named("u_", dst)}, {}, 3))
            self.accumulated = sums[steps % 2]
            self.surface_uniforms = {**grid_uniforms, "u_origin": tuple(map(float, grid.origin)),
                                     "u_cell": float(grid.cell), "u_scale": tuple(map(float, scales[steps - 1]))}
        except Exception:
            self.release()
            raise

    @property
    def surface_textures(self) -> dict:
        """The final pass's samplers: the accumulation grid and the medium (its weights)."""
        return {"u_medium": self.material["u_medium"], **{f"u_sum_{c}": t for c, t in zip(CHANNELS, self.accumulated)}}

    def run(self, injected: np.ndarray | None = None) -> None:
        """Passes 1-3, then bind the target framebuffer again.

        Parameters
        ----------
        injected : (nz, ny, nx, 4) float, optional
            Injected lobes (white light) to propagate instead of the shadow map's.
        """
        import moderngl

        self.ctx.enable(moderngl.DEPTH_TEST)
        for p in self._first:
            p.run()
        self.ctx.disable(moderngl.DEPTH_TEST)
        if injected is None:
            self.ctx.enable(moderngl.BLEND)
            self.ctx.blend_func = moderngl.ONE, moderngl.ONE
            self._inject.run()
            self.ctx.disable(moderngl.BLEND)
        else:
            nx, ny, nz = self.grid.shape
            lobes = np.asarray(injected, dtype=np.float32)
            if lobes.shape != (nz, ny, nx, 4) or not np.all(np.isfinite(lobes)):
                raise ValueError(f"lpv runtime: injected lobes must be finite with shape {(nz, ny, nx, 4)}, "
                                 f"got {lobes.shape}")
            self._inject.framebuffer.color_attachments[0].write(np.ascontiguousarray(lobes).tobytes())
        self._clear.clear(0.0, 0.0, 0.0, 0.0)
        for p in self._steps:
            p.run()
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.target.use()

    def read(self) -> dict:
        """The last run's grids, (nz, ny, nx, ...) float32: ``injected`` (4,) lobes and
        ``accumulated`` (3, 4) SH coefficients per channel."""
        nx, ny, nz = self.grid.shape
        injected = read_texture(self._inject.framebuffer.color_attachments[0], 4).reshape(nz, ny, nx, 4)
        accumulated = np.stack([read_texture(t, 4).reshape(nz, ny, nx, 4) for t in self.accumulated], axis=3)
        return {"injected": injected, "accumulated": accumulated}


class LpvDraw(DrawKind):
    """``lpv`` items (`render.Renderer.render`): ``lpv`` (`LpvGrid`, in the item's object frame) with
    ``lpv_matrices`` (6, 4, 4), ``lpv_scales`` (S, 3) and optionally ``lpv_steps`` and
    ``lpv_shadow_size`` (`propagate.LpvPropagateOptions`). `LpvPasses`, then ``lpv_surface.frag`` reads
    the accumulated intensity per pixel."""

    program = ("plain.vert", "lpv_surface.frag")

    def check(self, i: int, item: dict) -> None:
        check_data(i, item, "lpv", LpvGrid)
        matrices, scales = np.asarray(item.get("lpv_matrices")), np.asarray(item.get("lpv_scales"))
        if matrices.shape != (6, 4, 4) or scales.ndim != 2 or scales.shape[1] != 3 or not len(scales):
            raise ValueError(f"render: item {i}: lpv needs lpv_matrices (6, 4, 4) and lpv_scales (S, 3), got "
                             f"{matrices.shape} and {scales.shape}")

    def passes(self, renderer, item: dict, camera, light) -> LpvPasses:
        view_projection, extent, tan_half = item_light_camera(item, light)
        return LpvPasses(renderer.ctx, renderer.program, item, light, view_projection, extent, tan_half, renderer.fbo)

    def setup(self, renderer, program, item: dict, passes: LpvPasses) -> tuple[list, list]:
        for name, value in passes.surface_uniforms.items():
            program[name].value = value
        return super().setup(renderer, program, item, passes)


LPV_DRAW = LpvDraw()
