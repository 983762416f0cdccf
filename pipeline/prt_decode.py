"""Decoding `PrtData` the way the GLSL runtime does (``runtime_shaders/prt_decode.glsl``), and its
storage cost per vertex."""

from __future__ import annotations

import numpy as np

from .directions import DirectionSet, lookup_weights
from .prt_data import PrtData
from .sh import sh_basis


def decode_at_directions(prt: PrtData) -> np.ndarray:
    """q as the runtime reconstructs it at the set's own directions.

    Parameters
    ----------
    prt : PrtData

    Returns
    -------
    (3, n, K) float64
    """
    n, k = prt.vertex_count, len(prt.directions)
    out = np.zeros((3, n, k))
    if len(prt.ref_codes):
        w = decode_weights(prt.weight_codes, prt.weight_scale)
        corners = prt.ref_triangles[prt.vertex_triangle]
        lut = prt.lut.astype(np.float64)
        for c in range(3):
            out[c] = blend(w, lut[c][prt.ref_codes[:, :, c]], corners)
    if prt.sh_order:
        basis = sh_basis(prt.directions.astype(np.float64), prt.sh_order)  # (K, C)
        out += np.einsum("nci,ki->cnk", decode_int8(prt.dq_codes, prt.dq_scale), basis)
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
    ds = DirectionSet(prt.directions.astype(np.float64), prt.direction_triangles.astype(np.int64),
                      prt.direction_inverse.astype(np.float64), prt.direction_lookup, prt.direction_neighbours)
    index, beta = lookup_weights(ds, omega)  # (m, 3) directions and their weights
    out = np.zeros((3, m))
    if len(prt.ref_codes):
        w = decode_weights(prt.weight_codes[vertices], prt.weight_scale)
        corners = prt.ref_triangles[prt.vertex_triangle[vertices]]
        lut = prt.lut.astype(np.float64)
        for c in range(3):
            for r in range(3):
                table = lut[c][prt.ref_codes[corners[:, r][:, None], index, c]]  # (m, 3 directions)
                out[c] += w[:, r] * np.einsum("ma,ma->m", beta, table)
    if prt.sh_order:
        basis = sh_basis(omega / np.linalg.norm(omega, axis=1, keepdims=True), prt.sh_order)  # (m, C)
        out += np.einsum("mci,mi->cm", decode_int8(prt.dq_codes[vertices], prt.dq_scale), basis)
    return out


def bytes_per_vertex(prt: PrtData) -> dict[str, float]:
    """Every byte of the prt data per surface vertex as the glTF export stores it, tables amortised.

    Per vertex: ``_SSS_PRT_REF`` 4 B (2 × uint16), ``_SSS_PRT_W`` 4 B (2 × int16), ``_SSS_PRT_DQ*``
    3·C int8 codes padded to whole VEC4s. Tables (`prt_layout.prt_tables`; integer tables are
    written as uint32, floats as float32), divided by n: reference codes R·K·3, reference
    triangles, directions, hull triangles, inverses, lookup, neighbours, LUT and Δq scales. Render
    vertices duplicated at seams repeat the per-vertex part; buffer-view alignment (< 4 B per
    table) is left out.

    Returns
    -------
    dict
        Block name -> bytes per vertex, plus ``per_vertex``, ``tables`` and ``total``.
    """
    n = max(prt.vertex_count, 1)
    per_vertex = {"_SSS_PRT_REF": 4.0, "_SSS_PRT_W": 4.0,
                  "_SSS_PRT_DQ": 4.0 * -(-3 * prt.sh_order ** 2 // 4)}
    tables = {
        "refCodes": prt.ref_codes.size,
        "refTriangles": 4 * prt.ref_triangles.size,
        "directions": 4 * prt.directions.size,
        "directionTriangles": 4 * prt.direction_triangles.size,
        "directionInverse": 4 * prt.direction_inverse.size,
        "directionLookup": 4 * prt.direction_lookup.size,
        "directionNeighbours": 4 * prt.direction_neighbours.size,
        "lut": 4 * prt.lut.size,
        "dqScale": 4 * prt.dq_scale.size,
    }
    out = {**per_vertex, **{key: value / n for key, value in tables.items()}}
    out["per_vertex"] = sum(per_vertex.values())
    out["tables"] = sum(tables.values()) / n
    out["total"] = out["per_vertex"] + out["tables"]
    return out


def decode_int8(codes: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(n, 3, C) float64 values of int8 Δq codes: scale · code / 127."""
    return codes.astype(np.float64) / 127.0 * scale.astype(np.float64)


def decode_weights(codes: np.ndarray, scale: float) -> np.ndarray:
    """(n, 3) weights from (n, 2) int16 codes: w_0, w_1 = scale · code / 32767, w_2 = 1 - w_0 - w_1."""
    w01 = codes.astype(np.float64) / 32767.0 * scale
    return np.column_stack([w01, 1.0 - w01.sum(axis=1)])


def blend(w: np.ndarray, table: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(n, K) Σ_k w[:, k] · table[corners[:, k]] for one channel's (R, K) table."""
    return sum(w[:, k:k + 1] * table[corners[:, k]] for k in range(3))
