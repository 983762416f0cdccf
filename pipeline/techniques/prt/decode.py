"""Decoding `PrtData` the way the GLSL runtime does (``runtime_shaders/prt_decode.glsl``), and its
storage cost per vertex."""

from __future__ import annotations

import numba
import numpy as np

from sssbake.pipeline.core.directions import DirectionSet, lookup_weights
from sssbake.pipeline.core.sh import sh_basis
from sssbake.pipeline.mesh.baked import index_table
from sssbake.pipeline.techniques.prt.data import PrtData


def decode_at_directions(prt: PrtData, vertices: slice = slice(None)) -> np.ndarray:
    """q as the runtime reconstructs it at the set's own directions.

    Parameters
    ----------
    prt : PrtData
    vertices : slice
        The surface vertices to decode (all by default; a range bounds the output's memory).

    Returns
    -------
    (3, m, K) float64
        For the m vertices of `vertices`.
    """
    vertex_triangle = prt.vertex_triangle[vertices]
    n, k = len(vertex_triangle), len(prt.directions)
    out = np.zeros((3, n, k))
    if len(prt.ref_codes):
        w = decode_weights(prt.weight_codes[vertices], prt.weight_scale, prt.weight_bits)
        corners = prt.ref_triangles[vertex_triangle]
        tables = reference_tables(prt.ref_codes, prt.lut, prt.ref_scale)
        if prt.detail_order:
            tables += reference_detail(prt.detail_codes, prt.detail_colour, prt.detail_scale, prt.detail_order,
                                       prt.directions)
        for c in range(3):
            out[c] = blend(w, tables[c], corners)
    if prt.sh_order:
        basis = sh_basis(prt.directions.astype(np.float64), prt.sh_order)  # (K, C)
        out += np.einsum("nci,ki->cnk", decode_int8(prt.dq_codes[vertices], prt.dq_scale), basis)
    return out


def evaluate(prt: PrtData, omega: np.ndarray, vertices: np.ndarray | None = None) -> np.ndarray:
    """q at arbitrary light directions, interpolated over the direction set as the GLSL does
    (octahedral lookup, hull walk, clamped barycentrics) plus the Δq spherical harmonics.

    Parameters
    ----------
    prt : PrtData
    omega : (3,) or (m, 3) float64
        Direction towards the light: one for all vertices (directional light) or one per vertex
        (point light); need not be unit length.
    vertices : (m,) int64, optional
        Surface vertices to evaluate (all by default).

    Returns
    -------
    (3, m) float64
    """
    vertices = np.arange(prt.vertex_count) if vertices is None else np.asarray(vertices, dtype=np.int64)
    if vertices.ndim != 1 or (len(vertices) and (vertices.min() < 0 or vertices.max() >= prt.vertex_count)):
        raise ValueError(f"prt decode: vertices must be a 1-D array of indices below {prt.vertex_count}")
    m = len(vertices)
    omega = np.asarray(omega, dtype=np.float64)
    if omega.shape not in ((3,), (m, 3)):
        raise ValueError(f"prt decode: omega must be (3,) or ({m}, 3), got {omega.shape}")
    omega = np.broadcast_to(omega, (m, 3))
    unit = omega / np.linalg.norm(omega, axis=1, keepdims=True)
    ds = DirectionSet(prt.directions.astype(np.float64), prt.direction_triangles.astype(np.int64),
                      prt.direction_inverse.astype(np.float64), prt.direction_lookup, prt.direction_neighbours)
    index, beta = lookup_weights(ds, omega)  # (m, 3) directions and their weights
    out = np.zeros((3, m))
    if len(prt.ref_codes):
        w = decode_weights(prt.weight_codes[vertices], prt.weight_scale, prt.weight_bits)
        corners = prt.ref_triangles[prt.vertex_triangle[vertices]]
        tables = reference_tables(prt.ref_codes, prt.lut, prt.ref_scale)
        if prt.detail_order:  # at ω itself: per vertex, each corner's detail shape
            y = sh_basis(unit, prt.detail_order) * prt.detail_scale.astype(np.float64)  # (m, D)
        for r in range(3):
            if prt.detail_order:
                shape = np.einsum("mi,mi->m", prt.detail_codes[corners[:, r]].astype(np.float64), y) / 127.0
                detail = prt.detail_colour[corners[:, r]].T.astype(np.float64) / 127.0 * shape  # (3, m)
            for c in range(3):
                table = tables[c][corners[:, r][:, None], index]  # (m, 3 directions)
                value = np.einsum("ma,ma->m", beta, table)
                out[c] += w[:, r] * (value + detail[c] if prt.detail_order else value)
    if prt.sh_order:
        basis = sh_basis(unit, prt.sh_order)  # (m, C)
        out += np.einsum("mci,mi->cm", decode_int8(prt.dq_codes[vertices], prt.dq_scale), basis)
    return out


def reference_detail(codes: np.ndarray, colour: np.ndarray, scale: np.ndarray, order: int,
                     directions: np.ndarray) -> np.ndarray:
    """The reference points' detail terms D_c[r](ω) (`prt_data`) at unit directions.

    Parameters
    ----------
    codes : (R, D) int8
    colour : (R, 3) int8
    scale : (D,) float32
    order : int
        D = order².
    directions : (K, 3)

    Returns
    -------
    (3, R, K) float64
    """
    y = sh_basis(np.asarray(directions, dtype=np.float64), order) * np.asarray(scale, dtype=np.float64)  # (K, D)
    shape = codes.astype(np.float64) @ y.T / 127.0  # (R, K)
    return colour.T.astype(np.float64)[:, :, None] / 127.0 * shape[None]


def reference_tables(ref_codes: np.ndarray, lut: np.ndarray, ref_scale: np.ndarray) -> np.ndarray:
    """Reference tables at the set's directions as the runtime reads them: the LUT level of each
    code, times the reference point's colour for shared tables.

    Parameters
    ----------
    ref_codes : (R, K, C_t) uint8
    lut : (3, 256) float32
    ref_scale : (R, 3) float32 (C_t = 1) or (0, 3) (C_t = 3)

    Returns
    -------
    (3, R, K) float64
    """
    levels = lut.astype(np.float64)
    if ref_codes.shape[2] == 1:
        colour = ref_scale.T.astype(np.float64)[:, :, None]
        return np.stack([levels[c][ref_codes[:, :, 0]] for c in range(3)]) * colour
    return np.stack([levels[c][ref_codes[:, :, c]] for c in range(3)])


def bytes_per_vertex(prt: PrtData) -> dict[str, float]:
    """Every byte of the prt data per surface vertex as the glTF export stores it, tables amortised.

    Per vertex (`prt_layout`, VEC3 float32 attributes): ``_SSS_PRT_REF`` 12 B, ``_SSS_PRT_DQ*``
    12 B per SH coefficient (C of them). Tables (`prt_layout.prt_tables`; index tables as uint16 where they fit, else
    uint32; floats as float32), divided by n: reference codes R·K·C_t, reference colours (shared
    tables), reference triangles, directions, hull triangles, inverses, lookup, neighbours, LUT
    and Δq scales. Render vertices duplicated at seams repeat the per-vertex part; buffer-view
    alignment (< 4 B per table) is left out.

    Returns
    -------
    dict
        Block name -> bytes per vertex, plus ``per_vertex``, ``tables`` and ``total``.
    """
    n = max(prt.vertex_count, 1)
    per_vertex = {"_SSS_PRT_REF": 12.0, "_SSS_PRT_DQ": 12.0 * prt.sh_order ** 2}
    tables = {
        "refCodes": prt.ref_codes.size,
        "refScale": 4 * prt.ref_scale.size,
        "refTriangles": _index_bytes(prt.ref_triangles),
        "directions": 4 * prt.directions.size,
        "directionTriangles": _index_bytes(prt.direction_triangles),
        "directionInverse": 4 * prt.direction_inverse.size,
        "directionLookup": _index_bytes(prt.direction_lookup),
        "directionNeighbours": _index_bytes(prt.direction_neighbours),
        "lut": 4 * prt.lut.size,
        "dqScale": 4 * prt.dq_scale.size,
        "refDetail": prt.detail_codes.size + prt.detail_colour.size if prt.detail_order else 0,
        "detailScale": 4 * prt.detail_scale.size,
    }
    out = {**per_vertex, **{key: value / n for key, value in tables.items()}}
    out["per_vertex"] = sum(per_vertex.values())
    out["tables"] = sum(tables.values()) / n
    out["total"] = out["per_vertex"] + out["tables"]
    return out


def _index_bytes(values: np.ndarray) -> int:
    """Bytes of an index table as written: uint16 where it fits, else uint32."""
    return values.size * (2 if index_table(values).dtype == np.uint16 else 4)


def decode_int8(codes: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(n, 3, C) float64 values of int8 Δq codes: scale · code / 127."""
    return codes.astype(np.float64) / 127.0 * scale.astype(np.float64)


def weight_code_max(bits: int) -> int:
    """The code of weight_scale for `bits`-bit weight codes: 2^(bits - 1) - 1."""
    return (1 << (bits - 1)) - 1


def decode_weights(codes: np.ndarray, scale: float, bits: int) -> np.ndarray:
    """(n, 3) weights from (n, 2) codes: w_0, w_1 = scale · code / `weight_code_max` (bits),
    w_2 = 1 - w_0 - w_1."""
    w01 = codes.astype(np.float64) / weight_code_max(bits) * scale
    return np.column_stack([w01, 1.0 - w01.sum(axis=1)])


def blend(w: np.ndarray, table: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(n, K) Σ_k w[:, k] · table[corners[:, k]] for one channel's (R, K) table, in float64
    (`_blend_rows`)."""
    w, table = np.ascontiguousarray(w, dtype=np.float64), np.ascontiguousarray(table, dtype=np.float64)
    out = np.empty((len(w), table.shape[1]))
    _blend_rows(w, table, np.ascontiguousarray(corners, dtype=np.int64), out)
    return out


@numba.njit(cache=True, nogil=True)
def _blend_rows(w, table, corners, out):
    """`blend` row by row, in numpy's order ``0 + w_0 t_0 + w_1 t_1 + w_2 t_2`` (the same values
    as ``sum(w[:, k:k + 1] * table[corners[:, k]] for k in range(3))``, without its gathered
    (n, K) copies: ~6x faster)."""
    for v in range(len(w)):
        a, b, c = table[corners[v, 0]], table[corners[v, 1]], table[corners[v, 2]]
        for k in range(table.shape[1]):
            out[v, k] = 0.0 + w[v, 0] * a[k] + w[v, 1] * b[k] + w[v, 2] * c[k]
