"""The kernels technique (Lensch et al. 2002) on the GPU with moderngl: `KernelsData` uploaded as
textures and steps 1-4 of `kernels_data` as per-frame fragment passes (no compute shaders, so the
shaders stay GLSL 3.30 and ES 3.00); `render` adds the final draw (``kernels_surface.vert`` /
``.frag``, step 5).

Passes, each into a float texture:

1. shadow map: depth from the light (``plain.vert``, ``depth_only.frag``);
2. illumination map E, W × H R32F: border texels as one-pixel points, then the mesh triangles at
   their atlas UVs (``kernels_atlas.vert``, ``kernels_illumination.frag``);
3. local response, W × H RGBA32F: ``kernels_filter.frag`` (rgb B_l, alpha coverage);
4. distribution then global response, per-vertex RGBA32F: ``kernels_gather.frag`` twice, giving
   (B_d, E_g) and B_g.

Layouts. Atlas textures hold atlas row r in texture row r: the atlas pass sends v = 0 to
framebuffer row 0, which is texture row 0, and ``texture(map, uv)`` reads glTF UVs as they are, so
nothing is flipped. Per-vertex textures hold welded vertex j at texel (j % w, j / w), w =
min(table width, n). Long tables (kernel weights, CSR entries) are wrapped the same way by
`gl_passes.table_texture`, each widened past the table width where its rows would pass
GL_MAX_TEXTURE_SIZE (`wrap_width`: up to limit² entries a table); the shaders never divide: a texel's kernel, a CSR row and an entry's
source are given as texels, computed here. `KERNELS_DRAW` is the renderer's ``kernels`` draw.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.render.gl_passes import (
    SHADOW_OFFSET_TEXELS,
    OwnedObjects,
    Pass,
    gl_matrix,
    read_texture,
    shadow_texture,
    table_texture,
)
from sssbake.pipeline.render.renderer import DrawKind, check_array, check_data, item_light_camera
from sssbake.pipeline.techniques.kernels.data import KernelsData

#: Vertex and fragment stage of each offscreen pass.
PASS_PROGRAMS = {"shadow": ("plain.vert", "depth_only.frag"),
                 "illumination": ("kernels_atlas.vert", "kernels_illumination.frag"),
                 "filter": ("fullscreen.vert", "kernels_filter.frag"), "gather": ("fullscreen.vert", "kernels_gather.frag")}


class KernelsPasses(OwnedObjects):
    """One kernels item's GL objects and passes 1-4.

    Parameters
    ----------
    ctx : moderngl.Context
    program : callable
        ``program(vertex_file, fragment_file) -> moderngl.Program`` (the renderer's cache).
    item : dict
        A checked render item of kind ``"kernels"`` (see `render.Renderer.render`).
    light : render.RenderLight
    light_view_projection : (4, 4) float64
        World to the shadow map's clip space (`render.light_camera`).
    shadow_extent : float
        World width the shadow map spans at the item (sets the size of a shadow texel).
    target : moderngl.Framebuffer
        Bound again, with its viewport, after the passes.
    table_width : int
        Width of the wrapped layouts.
    shadow_size : int
        Shadow map side in texels.
    """

    def __init__(self, ctx, program, item: dict, light, light_view_projection: np.ndarray, shadow_extent: float,
                 target, table_width: int, shadow_size: int):
        import moderngl

        self.ctx, self.target = ctx, target
        self.data: KernelsData = item["kernels"]
        super().__init__()
        self._limit = ctx.info["GL_MAX_TEXTURE_SIZE"]
        w, h, n = self.data.width, self.data.height, self.data.vertex_count
        self.vertex_width = wrap_width(n, table_width, self._limit)
        vertex_size = (self.vertex_width, -(-n // self.vertex_width))
        if max(w, h) > self._limit:
            raise ValueError(f"kernels runtime: a {w} x {h} atlas is over GL_MAX_TEXTURE_SIZE {self._limit}")
        if vertex_size[1] > self._limit:
            raise ValueError(f"kernels runtime: {n} vertices need {vertex_size[1]} rows of {self.vertex_width} "
                             f"texels, over GL_MAX_TEXTURE_SIZE {self._limit}")
        try:
            self.illumination = self._keep(ctx.texture((w, h), 1, dtype="f4"))
            self.local = self._keep(ctx.texture((w, h), 4, dtype="f4"))
            self.local.repeat_x = self.local.repeat_y = False  # bilinear reads at the atlas edge clamp
            self.direct = self._keep(ctx.texture(vertex_size, 4, dtype="f4"))
            self.global_ = self._keep(ctx.texture(vertex_size, 4, dtype="f4"))
            for tex in (self.illumination, self.direct, self.global_):
                tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._response_passes = self._response(program, table_width)
            self._light_passes = self._lighting(program, item, light, light_view_projection, shadow_extent,
                                                shadow_size)
        except Exception:
            self.release()
            raise

    def _response(self, program, table_width: int) -> list[Pass]:
        """Steps 2-4: their tables and passes."""
        import moderngl

        data, ctx = self.data, self.ctx
        w, h, n = data.width, data.height, data.vertex_count

        def table(name, rows, dtype, width=table_width):
            return self._keep(table_texture(ctx, np.ascontiguousarray(rows), dtype,
                                            wrap_width(len(rows), width, self._limit), self._limit,
                                            f"kernels runtime: {name}"))

        # Step 2: a texel's k² weights are consecutive; the W x H map points at the first.
        kernels = table("kernels", data.kernels.reshape(-1, 3).astype(np.float32), "f4")
        first = np.full((h * w, 2), -1, dtype=np.int32)
        first[data.texels] = _texels(np.arange(len(data.texels)) * data.kernel_size ** 2, kernels.width)
        texel_kernel = self._keep(ctx.texture((w, h), 2, first.tobytes(), dtype="i4"))
        texel_kernel.filter = (moderngl.NEAREST, moderngl.NEAREST)

        # Step 3: texel -> corner transposed to CSR by vertex.
        corners = data.texel_vertices.reshape(-1)
        order = np.argsort(corners, kind="stable")
        weights = np.column_stack([data.texel_direct.reshape(-1, 3)[order], data.texel_dual.reshape(-1)[order]])
        corner_entries = table("texel corners", _texels(np.repeat(data.texels, 3)[order], w), "i4")
        corner_weights = table("texel corners", weights.astype(np.float32), "f4")
        corner_rows = table("vertices", _rows(np.bincount(corners, minlength=n), corner_entries.width), "i4",
                            self.vertex_width)

        # Step 4: F's rows; an entry's source is a texel of the per-vertex layout.
        f_entries = table("F", _texels(data.f_indices, self.vertex_width), "i4")
        f_values = table("F", data.f_values.astype(np.float32), "f4")
        f_rows = table("vertices", _rows(np.diff(data.f_indptr), f_entries.width), "i4", self.vertex_width)

        local = program(*PASS_PROGRAMS["filter"])
        gather = program(*PASS_PROGRAMS["gather"])
        screen = self._keep(ctx.vertex_array(local, []))
        gather_screen = self._keep(ctx.vertex_array(gather, []))
        return [
            Pass(local, screen, self._target(self.local),
                  {"u_illumination": self.illumination, "u_texel_kernel": texel_kernel, "u_kernels": kernels},
                  {"u_kernel_radius": data.radius}, 3),
            Pass(gather, gather_screen, self._target(self.direct),
                  {"u_rows": corner_rows, "u_entries": corner_entries, "u_weights": corner_weights,
                   "u_source": self.illumination}, {"u_channel": 0}, 3),
            Pass(gather, gather_screen, self._target(self.global_),
                  {"u_rows": f_rows, "u_entries": f_entries, "u_weights": f_values, "u_source": self.direct},
                  {"u_channel": 3}, 3),
        ]

    def _lighting(self, program, item, light, light_view_projection, shadow_extent, shadow_size) -> list[Pass]:
        """Steps 1 (shadow map, then E): geometry and passes."""
        import moderngl

        data, ctx = self.data, self.ctx
        # One point per border texel at its centre, its surface point blended in object space from
        # any render vertex of each welded vertex (the model matrix is affine, the normal matrix
        # linear: blending commutes with both), then the mesh; the shadow map holds the mesh only.
        render_vertex = np.zeros(data.surface_vertex_count, dtype=np.int64)
        render_vertex[item["vertex_ids"]] = np.arange(len(item["vertex_ids"]))
        border_corners = render_vertex[data.border_vertices]
        points = len(border_corners)
        rows, cols = np.divmod(data.border_texels, data.width)
        centres = np.column_stack([(cols + 0.5) / data.width, (rows + 0.5) / data.height])
        arrays = [(np.concatenate([np.einsum("ba,bad->bd", data.border_barycentric,
                                             np.asarray(item[key])[border_corners]), item[key]]), fmt, name)
                  for key, fmt, name in (("positions", "3f", "in_position"), ("normals", "3f", "in_normal"))]
        arrays.append((np.concatenate([centres, item["uvs"]]), "2f", "in_uv"))
        buffers = [self._keep(ctx.buffer(np.ascontiguousarray(a, np.float32).tobytes())) for a, _, _ in arrays]
        indices = self._keep(ctx.buffer(np.concatenate([np.arange(points), np.asarray(item["faces"]).reshape(-1)
                                                        + points]).astype(np.uint32).tobytes()))
        triangles = 3 * len(item["faces"])

        def vao(prog):
            content = [(buf, fmt, name) for buf, (_, fmt, name) in zip(buffers, arrays) if name in prog]
            return self._keep(ctx.vertex_array(prog, content, index_buffer=indices, index_element_size=4))

        shadow_map = self._keep(shadow_texture(ctx, shadow_size))
        model = np.asarray(item["model"], dtype=np.float64)
        transforms = {"u_model": gl_matrix(model), "u_normal_matrix": gl_matrix(np.linalg.inv(model[:3, :3]).T),
                      "u_view_projection": gl_matrix(light_view_projection)}
        lighting = {**transforms, "u_eta": float(item["eta"]), "u_point_light": int(light.point),
                    "u_light": tuple(map(float, light.vector)), "u_intensity": float(light.intensity),
                    "u_mm_per_unit": float(light.mm_per_unit), "u_light_view_projection": gl_matrix(light_view_projection),
                    "u_shadow_offset": SHADOW_OFFSET_TEXELS * shadow_extent / shadow_size}
        shadow = program(*PASS_PROGRAMS["shadow"])
        lit = program(*PASS_PROGRAMS["illumination"])
        lit_vao, lit_target = vao(lit), self._target(self.illumination)
        return [
            Pass(shadow, vao(shadow), self._keep(ctx.framebuffer(depth_attachment=shadow_map)), {}, transforms,
                  triangles, points, clear=True),
            Pass(lit, lit_vao, lit_target, {"u_shadow": shadow_map}, lighting, points, clear=True,
                  mode=moderngl.POINTS),
            Pass(lit, lit_vao, lit_target, {"u_shadow": shadow_map}, lighting, triangles, points),
        ]

    @property
    def surface_textures(self) -> dict:
        """The final pass's samplers: local response (bilinear), B_d and B_g."""
        return {"u_local": self.local, "u_direct": self.direct, "u_global": self.global_}

    def vertex_texels(self, vertex_ids: np.ndarray) -> np.ndarray:
        """(m, 2) int32 texel of each global vertex in `vertex_ids` in the per-vertex textures."""
        return _texels(np.asarray(vertex_ids), self.vertex_width)

    def surface_attributes(self, vertex_ids: np.ndarray) -> list[tuple[np.ndarray, str, str]]:
        """The final draw's per-render-vertex inputs for welded surface vertices `vertex_ids` (m,):
        the texels of the three global vertices each reads and their weights (step 5)."""
        ids = np.asarray(vertex_ids)
        corners = self.data.surface_global[ids]
        return [(self.vertex_texels(corners[:, a]), "2i", f"in_global_texel{a}") for a in range(3)] + [
            (self.data.surface_weights[ids].astype(np.float32), "3f", "in_global_weight")]

    def run(self, illumination: np.ndarray | None = None) -> None:
        """Passes 1-4, then bind the target framebuffer again.

        Parameters
        ----------
        illumination : (height, width) float, optional
            E to filter and distribute instead of rendering passes 1-2 (row 0 = atlas row 0).
        """
        import moderngl

        self.ctx.enable(moderngl.DEPTH_TEST)  # for the shadow map; targets without depth pass all
        if illumination is None:
            for p in self._light_passes:
                p.run()
        else:
            e = np.asarray(illumination, dtype=np.float32)
            if e.shape != (self.data.height, self.data.width) or not np.all(np.isfinite(e)):
                raise ValueError(f"kernels runtime: illumination must be finite with shape "
                                 f"{(self.data.height, self.data.width)}, got {e.shape}")
            self.illumination.write(np.ascontiguousarray(e).tobytes())
        for p in self._response_passes:
            p.run()
        self.target.use()

    def read(self) -> dict:
        """The last run's results.

        Returns
        -------
        dict
            ``illumination`` (height, width) float32, row 0 = atlas row 0; ``local`` (S, 3) B_l at
            ``texels``; ``e_g`` (n,); ``b_d`` (n, 3); ``b_g`` (n, 3).
        """
        d = self.data
        e = read_texture(self.illumination, 1).reshape(d.height, d.width)
        direct = read_texture(self.direct, 4)[: d.vertex_count]
        return {"illumination": e, "local": read_texture(self.local, 4)[d.texels, :3], "e_g": direct[:, 3],
                "b_d": direct[:, :3], "b_g": read_texture(self.global_, 4)[: d.vertex_count, :3]}

    def _target(self, texture):
        return self._keep(self.ctx.framebuffer(color_attachments=[texture]))


def wrap_width(count: int, width: int, limit: int) -> int:
    """Width of a table of `count` entries wrapped `width` wide, widened (up to `limit`) until its
    rows fit `limit`; a table over limit² entries keeps `limit` and is refused by the caller."""
    return min(limit, max(min(width, max(count, 1)), -(-count // limit)))


def _texels(index: np.ndarray, width: int) -> np.ndarray:
    """(m, 2) int32 (index % width, index // width): where a wrapped table holds entry `index`."""
    index = np.asarray(index, dtype=np.int64)
    return np.column_stack([index % width, index // width]).astype(np.int32)


def _rows(counts: np.ndarray, width: int) -> np.ndarray:
    """(n, 4) int32 per CSR row: texel of its first entry in a table `width` wide, entry count, 0."""
    counts = np.asarray(counts, dtype=np.int64)
    rows = np.zeros((len(counts), 4), dtype=np.int32)
    rows[:, :2] = _texels(np.cumsum(counts) - counts, width)
    rows[:, 2] = counts
    return rows


class KernelsDraw(DrawKind):
    """``kernels`` items (`render.Renderer.render`): ``kernels`` (`KernelsData`) with ``uvs`` (n, 2)
    atlas UVs (glTF convention) and ``vertex_ids`` (n,) int, the welded surface vertex of each
    render vertex. `KernelsPasses` (its shadow map holds the item's own triangles), then
    ``kernels_surface.vert`` / ``.frag`` draw q = B_l(uv) + B_g + B_d."""

    program = ("kernels_surface.vert", "kernels_surface.frag")

    def check(self, i: int, item: dict) -> None:
        n = len(item["positions"])
        check_array(i, item, "uvs", (n, 2))
        data = item["kernels"]
        check_data(i, item, "kernels", KernelsData)
        ids = np.asarray(item["vertex_ids"])
        count = data.surface_vertex_count
        if ids.shape != (n,) or not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0 or ids.max() >= count:
            raise ValueError(f"render: item {i}: vertex_ids must be ({n},) integers in 0..{count - 1}")
        if not np.all(np.isin(data.border_vertices, ids)):
            raise ValueError(f"render: item {i}: border texels use welded vertices no render vertex maps to")

    def passes(self, renderer, item: dict, camera, light) -> KernelsPasses:
        view_projection, extent, _ = item_light_camera(item, light)
        return KernelsPasses(renderer.ctx, renderer.program, item, light, view_projection, extent, renderer.fbo,
                             renderer.table_width, renderer.shadow_size)

    def setup(self, renderer, program, item: dict, passes: KernelsPasses) -> tuple[list, list]:
        attributes = [(np.asarray(item["uvs"], np.float32), "2f", "in_uv"),
                      *passes.surface_attributes(item["vertex_ids"])]
        return attributes, super().setup(renderer, program, item, passes)[1]


KERNELS_DRAW = KernelsDraw()
