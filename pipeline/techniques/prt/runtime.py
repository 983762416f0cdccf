"""Hand `PrtData` to the GLSL decoder (``runtime_shaders/prt_decode.glsl``) with moderngl:
its tables as textures, its per-vertex codes as vertex attributes and one integer texture; the
renderer's ``prt`` draw (`PRT_DRAW`)."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.sh import MAX_ORDER as SH_MAX_ORDER
from sssbake.pipeline.render.gl_passes import table_texture
from sssbake.pipeline.render.renderer import TABLE_WIDTH, DrawKind
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.layout import detail_rows


class PrtDraw(DrawKind):
    """``prt`` items (`render.Renderer.render`): ``prt`` (`PrtData` over the item's n vertices, q
    per unit irradiance), which ``prt.vert`` decodes per vertex, one program variant per SH order
    and weight layout (`shader_defines`)."""

    program = ("prt.vert", "sss_surface.frag")

    def check(self, i: int, item: dict) -> None:
        n, prt = len(item["positions"]), item["prt"]
        if not isinstance(prt, PrtData) or prt.vertex_count != n or not 0 <= prt.sh_order <= SH_MAX_ORDER:
            raise ValueError(f"render: item {i}: prt must be PrtData over the item's {n} vertices, "
                             f"SH order <= {SH_MAX_ORDER}")

    def defines(self, item: dict) -> str:
        return shader_defines(item["prt"])

    def setup(self, renderer, program, item: dict, passes) -> tuple[list, list]:
        # `upload` also sets the item's prt uniforms, which the renderer's draw keeps
        return per_vertex_arrays(item["prt"]), upload(renderer.ctx, program, item["prt"], width=renderer.table_width)


def per_vertex_arrays(prt: PrtData) -> list[tuple[np.ndarray, str, str]]:
    """The per-vertex attribute as stored (`prt_layout`), as (array, moderngl format, shader
    input): ``in_prt_ref`` (n, 3) float32, the reference triangle and the two weight codes."""
    ref = np.column_stack([prt.vertex_triangle, prt.weight_codes]).astype(np.float32)
    return [(ref, "3f4", "in_prt_ref")]


def shader_defines(prt: PrtData) -> str:
    """The ``#define`` lines ``prt_decode.glsl`` needs for `prt`: its SH and detail orders (a
    variant per order, see the shader) and PRT_COMPACT for 8-bit weight codes."""
    return (f"#define PRT_SH_ORDER {prt.sh_order}\n#define PRT_DETAIL_ORDER {prt.detail_order}\n"
            + ("#define PRT_COMPACT\n" if prt.weight_bits == 8 else ""))


def upload(ctx, program, prt: PrtData, width: int = TABLE_WIDTH) -> list:
    """Create the textures and set the uniforms of `program` for `prt`; returns the textures
    (keep them alive while drawing)."""
    import moderngl

    k = len(prt.directions)
    limit = ctx.info["GL_MAX_TEXTURE_SIZE"]
    tables = {
        # shared tables: one code per texel (R8UI); RGB: three (RGBA8UI)
        "u_prt_ref_codes": (prt.ref_codes.reshape(-1, 1) if prt.ref_codes.shape[2] == 1
                            else _pad4(prt.ref_codes.reshape(-1, 3), np.uint8), "u1"),
        "u_prt_ref_scale": (_pad4(prt.ref_scale, np.float32), "f4"),
        "u_prt_ref_tris": (_pad4(prt.ref_triangles, np.int32), "i4"),
        "u_prt_lut": (_pad4(prt.lut.T, np.float32), "f4"),
        "u_prt_dir_tris": (_pad4(prt.direction_triangles, np.int32), "i4"),
        "u_prt_dir_neigh": (_pad4(prt.direction_neighbours, np.int32), "i4"),
        "u_prt_dir_inv": (_pad4(prt.direction_inverse.reshape(-1, 3), np.float32), "f4"),
        "u_prt_dq": (prt.dq_codes.reshape(-1, 1).astype(np.int32), "i4"),
        "u_prt_detail": (_detail_texels(prt), "i1"),
    }
    textures = []
    unit = 0
    for name, (rows, dtype) in tables.items():
        tex = table_texture(ctx, rows, dtype, width if name != "u_prt_lut" else 256, limit,
                            "prt runtime: a table")
        textures.append(tex)
        if name in program:
            tex.use(unit)
            program[name].value = unit
        unit += 1
    lookup = ctx.texture(prt.direction_lookup.shape[::-1], 1, np.ascontiguousarray(prt.direction_lookup, np.int32).tobytes(),
                         dtype="i4")
    lookup.filter = (moderngl.NEAREST, moderngl.NEAREST)
    lookup.use(unit)
    textures.append(lookup)
    uniforms = {
        "u_prt_dir_lookup": unit,
        "u_prt_k": k,
        "u_prt_refs": len(prt.ref_codes),
        "u_prt_ref_channels": int(prt.ref_codes.shape[2]),
        "u_prt_order": prt.sh_order,
        "u_prt_detail_order": prt.detail_order,
        "u_prt_weight_scale": float(prt.weight_scale),
        "u_prt_lookup_size": int(prt.direction_lookup.shape[0]),
    }
    for name, value in uniforms.items():
        if name in program:
            program[name].value = value
    for name, values in (("u_prt_dq_scale", prt.dq_scale), ("u_prt_detail_scale", prt.detail_scale)):
        if values.size and name in program:
            scale = np.zeros(program[name].array_length, dtype=np.float32)
            scale[: values.size] = values.reshape(-1)
            program[name].write(scale.tobytes())
    return textures


def _detail_texels(prt: PrtData) -> np.ndarray:
    """(R · ceil((D + 3) / 4), 4) int8: `prt_layout.detail_rows` zero-padded to whole texels."""
    row = detail_rows(prt)
    width = 4 * -(-row.shape[1] // 4)
    padded = np.zeros((len(row), width), dtype=np.int8)
    padded[:, : row.shape[1]] = row
    return padded.reshape(-1, 4)


def _pad4(rows: np.ndarray, dtype) -> np.ndarray:
    """Rows widened to 4 components; an empty table becomes one zero row (GL has no empty textures)."""
    rows = np.asarray(rows)
    out = np.zeros((max(len(rows), 1), 4), dtype=dtype)
    if len(rows):
        flat = rows.reshape(len(rows), -1)
        out[: len(rows), : flat.shape[1]] = flat
    return out


PRT_DRAW = PrtDraw()
