"""The screen technique (Mertens et al. 2003) on the GPU with moderngl: a material's `ScreenSamples`
uploaded as two small textures and the per-frame passes before `render`'s final draw
(``plain.vert`` / ``screen_surface.frag``):

1. shadow map: depth from the light (``plain.vert``, ``depth_only.frag``);
2. G-buffer from the camera, two RGBA32F targets: world position and the entering irradiance E,
   unit normal and coverage (``plain.vert``, ``screen_gbuffer.frag``);
3. gather, RGBA32F: B per pixel from the sample tables (``fullscreen.vert``,
   ``screen_gather.frag``), alpha the share of Rd's integral the samples found on the surface;
4. resolve, RGBA32F: the interleaved rotations averaged over each pixel's tile-sized window of
   neighbouring surface (``fullscreen.vert``, ``screen_resolve.frag``; with interleaving only).

The paper's N accumulation passes (one per sample) are one here: a fragment loops over the
samples, the single pass it foresaw for later hardware. Nothing is baked per vertex, so the passes
serve deforming meshes as they are. `SCREEN_DRAW` is the renderer's ``screen`` draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.render.gl_passes import (
    SHADOW_OFFSET_TEXELS,
    OwnedObjects,
    Pass,
    gl_matrix,
    read_texture,
    shadow_texture,
)
from sssbake.pipeline.render.renderer import DrawKind, check_data, item_light_camera
from sssbake.pipeline.techniques.screen.data import ScreenSamples, table_total

#: Vertex and fragment stage of each offscreen pass.
PASS_PROGRAMS = {"shadow": ("plain.vert", "depth_only.frag"), "gbuffer": ("plain.vert", "screen_gbuffer.frag"),
                 "gather": ("fullscreen.vert", "screen_gather.frag"),
                 "resolve": ("fullscreen.vert", "screen_resolve.frag")}


@dataclass(frozen=True)
class ScreenRuntimeOptions:
    """Attributes
    ----------
    jacobian : bool
        Weight each sample by the projection's Jacobian (the paper omits it; it lowers the image
        RMSE: benchmarks/README.md#screen-jacobian).
    fill : bool
        Scale B by R_d over the share of Rd's integral found (missing surface lit like the found).
    interleave : int
        Side of the tile of per-pixel pattern rotations (1: every pixel the same pattern).
    resolve : bool
        Average the rotations over each pixel's interleave window (neighbours within the
        material's `ScreenSamples.uniform_radius_mm`, the widest channel's median radius).
    """

    jacobian: bool = True
    fill: bool = True
    interleave: int = 4
    resolve: bool = True

    def check(self) -> None:
        if not (isinstance(self.interleave, int) and 1 <= self.interleave <= 64):
            raise ValueError(f"screen runtime: interleave must be a whole number in [1, 64], got {self.interleave!r}")


SCREEN_RUNTIME_DEFAULTS = ScreenRuntimeOptions()


class ScreenPasses(OwnedObjects):
    """One screen item's GL objects and passes 1-4 (module docstring).

    Parameters
    ----------
    ctx, program, light, light_view_projection, shadow_extent, target, shadow_size
        As `kernels_runtime.KernelsPasses`'.
    item : dict
        A checked render item of kind ``"screen"`` (see `render.Renderer.render`).
    camera : render.Camera
    size : (width, height)
        The image's, which the G-buffer and gather match pixel for pixel.
    """

    def __init__(self, ctx, program, item: dict, light, light_view_projection: np.ndarray, shadow_extent: float,
                 camera, size: tuple[int, int], target, shadow_size: int):
        import moderngl

        self.ctx, self.target, self.size = ctx, target, size
        self.samples: ScreenSamples = item["screen"]
        options: ScreenRuntimeOptions = item.get("screen_runtime", SCREEN_RUNTIME_DEFAULTS)
        options.check()
        super().__init__()
        limit = ctx.info["GL_MAX_TEXTURE_SIZE"]
        count, entries = len(self.samples.offsets), self.samples.table.shape[1]
        if max(count, entries) > limit:
            raise ValueError(f"screen runtime: {count} samples and {entries} table entries must each fit "
                             f"GL_MAX_TEXTURE_SIZE {limit}")
        try:
            self.position = self._keep(ctx.texture(size, 4, dtype="f4"))
            self.normal = self._keep(ctx.texture(size, 4, dtype="f4"))
            self.scattered = self._keep(ctx.texture(size, 4, dtype="f4"))
            resolving = options.resolve and options.interleave > 1
            gathered = self._keep(ctx.texture(size, 4, dtype="f4")) if resolving else self.scattered
            rows = np.column_stack([self.samples.offsets, self.samples.weights, np.zeros(count)])
            sample_table = self._keep(ctx.texture((count, 1), 4, rows.astype(np.float32).tobytes(), dtype="f4"))
            rd = np.column_stack([self.samples.table.T, np.zeros(entries)])
            rd_table = self._keep(ctx.texture((entries, 1), 4, rd.astype(np.float32).tobytes(), dtype="f4"))
            shadow_map = self._keep(shadow_texture(ctx, shadow_size))
            for tex in (self.position, self.normal, self.scattered, gathered, sample_table, rd_table):
                tex.filter = (moderngl.NEAREST, moderngl.NEAREST)

            model = np.asarray(item["model"], dtype=np.float64)
            buffers = [self._keep(ctx.buffer(np.ascontiguousarray(item[key], np.float32).tobytes()))
                       for key in ("positions", "normals")]
            indices = self._keep(ctx.buffer(np.ascontiguousarray(item["faces"], np.uint32).tobytes()))
            triangles = 3 * len(item["faces"])

            def vao(prog):
                content = [(buf, "3f", name) for buf, name in zip(buffers, ("in_position", "in_normal")) if name in prog]
                return self._keep(ctx.vertex_array(prog, content, index_buffer=indices, index_element_size=4))

            transforms = {"u_model": gl_matrix(model), "u_normal_matrix": gl_matrix(np.linalg.inv(model[:3, :3]).T)}
            lighting = {**transforms, "u_view_projection": gl_matrix(camera.view_projection),
                        "u_eta": float(item["eta"]), "u_point_light": int(light.point),
                        "u_light": tuple(map(float, light.vector)), "u_intensity": float(light.intensity),
                        "u_mm_per_unit": float(light.mm_per_unit),
                        "u_light_view_projection": gl_matrix(light_view_projection),
                        "u_shadow_offset": SHADOW_OFFSET_TEXELS * shadow_extent / shadow_size}
            # mm per world unit: the item's mm per object unit over the model's (uniform) scale
            mm_per_world = float(item["mm_per_unit"]) / abs(np.linalg.det(model[:3, :3])) ** (1.0 / 3.0)
            gathering = {"u_view_projection": gl_matrix(camera.view_projection),
                         "u_eye": tuple(map(float, camera.eye)), "u_mm_per_world": mm_per_world,
                         "u_count": count, "u_jacobian": int(options.jacobian), "u_fill": int(options.fill),
                         "u_interleave": options.interleave, "u_reach_mm": float(self.samples.table_reach_mm),
                         "u_total": tuple(map(float, table_total(self.samples)))}
            shadow = program(*PASS_PROGRAMS["shadow"])
            gbuffer = program(*PASS_PROGRAMS["gbuffer"])
            gather = program(*PASS_PROGRAMS["gather"])
            self._first = [
                Pass(shadow, vao(shadow), self._keep(ctx.framebuffer(depth_attachment=shadow_map)), {},
                     {**transforms, "u_view_projection": gl_matrix(light_view_projection)}, triangles, clear=True),
                Pass(gbuffer, vao(gbuffer),
                     self._keep(ctx.framebuffer(color_attachments=[self.position, self.normal],
                                                depth_attachment=self._keep(ctx.depth_renderbuffer(size)))),
                     {"u_shadow": shadow_map}, lighting, triangles, clear=True),
            ]
            self._second = [Pass(gather, self._keep(ctx.vertex_array(gather, [])),
                                 self._keep(ctx.framebuffer(color_attachments=[gathered])),
                                 {"u_position": self.position, "u_normal": self.normal, "u_samples": sample_table,
                                  "u_rd": rd_table}, gathering, 3)]
            if resolving:
                resolve = program(*PASS_PROGRAMS["resolve"])
                self._second.append(Pass(resolve, self._keep(ctx.vertex_array(resolve, [])),
                                         self._keep(ctx.framebuffer(color_attachments=[self.scattered])),
                                         {"u_gathered": gathered, "u_position": self.position,
                                          "u_normal": self.normal},
                                         {"u_interleave": options.interleave, "u_mm_per_world": mm_per_world,
                                          "u_resolve_mm": float(self.samples.uniform_radius_mm)}, 3))
        except Exception:
            self.release()
            raise

    @property
    def surface_textures(self) -> dict:
        """The final pass's sampler: B per pixel."""
        return {"u_scattered": self.scattered}

    def run(self, irradiance: np.ndarray | None = None) -> None:
        """Passes 1-4, then bind the target framebuffer again.

        Parameters
        ----------
        irradiance : (height, width) float, optional
            E to gather (row 0 at the top, as images) instead of the one pass 2 lights; the
            positions and normals stay pass 2's.
        """
        import moderngl

        self.ctx.enable(moderngl.DEPTH_TEST)
        for p in self._first:
            p.run()
        if irradiance is not None:
            e = np.asarray(irradiance, dtype=np.float32)
            if e.shape != (self.size[1], self.size[0]) or not np.all(np.isfinite(e)):
                raise ValueError(f"screen runtime: irradiance must be finite with shape "
                                 f"{(self.size[1], self.size[0])}, got {e.shape}")
            texels = read_texture(self.position, 4)
            texels[:, 3] = e[::-1].reshape(-1)
            self.position.write(texels.tobytes())
        for p in self._second:
            p.run()
        self.target.use()

    def read(self) -> dict:
        """The last run's results, (height, width, ...) with row 0 at the top.

        Returns
        -------
        dict
            ``position`` (H, W, 3) world; ``irradiance`` (H, W) E; ``normal`` (H, W, 3);
            ``covered`` (H, W) bool; ``scattered`` (H, W, 3) B; ``share`` (H, W) the smallest
            share of Rd's integral the gather found, over the channels.
        """
        w, h = self.size
        position = read_texture(self.position, 4).reshape(h, w, 4)[::-1]
        normal = read_texture(self.normal, 4).reshape(h, w, 4)[::-1]
        scattered = read_texture(self.scattered, 4).reshape(h, w, 4)[::-1]
        return {"position": position[..., :3], "irradiance": position[..., 3], "normal": normal[..., :3],
                "covered": normal[..., 3] > 0.5, "scattered": scattered[..., :3], "share": scattered[..., 3]}


class ScreenDraw(DrawKind):
    """``screen`` items (`render.Renderer.render`): ``screen`` (`ScreenSamples`) with ``mm_per_unit``
    (mm per object unit) and optionally ``screen_runtime`` (`ScreenRuntimeOptions`).
    `ScreenPasses` from the image's camera (its G-buffer and shadow map hold the item alone), then
    ``screen_surface.frag`` reads B per pixel."""

    program = ("plain.vert", "screen_surface.frag")

    def check(self, i: int, item: dict) -> None:
        check_data(i, item, "screen", ScreenSamples)
        mm = item.get("mm_per_unit")
        if not isinstance(mm, (int, float)) or not (np.isfinite(mm) and mm > 0):
            raise ValueError(f"render: item {i}: a screen item needs mm_per_unit > 0 (mm per object unit), got {mm!r}")
        if not isinstance(item.get("screen_runtime", SCREEN_RUNTIME_DEFAULTS), ScreenRuntimeOptions):
            raise ValueError(f"render: item {i}: screen_runtime must be ScreenRuntimeOptions")

    def passes(self, renderer, item: dict, camera, light) -> ScreenPasses:
        if camera is None:
            raise ValueError("render: a screen item's passes need the image's camera")
        view_projection, extent, _ = item_light_camera(item, light)
        return ScreenPasses(renderer.ctx, renderer.program, item, light, view_projection, extent, camera,
                            renderer.size, renderer.fbo, renderer.shadow_size)


SCREEN_DRAW = ScreenDraw()
