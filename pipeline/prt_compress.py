"""prt compression (Hao & Varshney 2004 §4): reference points with Lloyd-quantised tables, and the
remainder Δq as low-order spherical harmonics in bytes. Produces `PrtData`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .directions import DirectionSet, lookup_weights
from .lloyd import lloyd_quantizer
from .prt_data import PrtData
from .reference_points import least_squares_weights, reference_points
from .sh import MAX_ORDER, sh_basis, sh_fit_matrix

MODES = ("refs+sh", "sh", "lloyd")
WEIGHTS = ("barycentric", "least_squares")


@dataclass(frozen=True)
class PrtCompressOptions:
    """Attributes
    ----------
    mode : str
        ``"refs+sh"`` (the paper's scheme), ``"sh"`` (SH of q alone) or ``"lloyd"`` (every vertex
        its own reference point: the uncompressed 8-bit baseline).
    reference_fraction : float
        Reference points as a fraction of the vertices (``refs+sh``).
    sh_order : int
        SH order n of Δq (n² coefficients per channel; 0 for none).
    weights : str
        ``"barycentric"`` or ``"least_squares"``.
    dq_percentile : float
        The int8 range of each SH coefficient covers this percentile of |coefficient|; larger ones
        clip (a few outliers would otherwise waste the range of all).
    """

    mode: str = "refs+sh"
    reference_fraction: float = 0.03
    sh_order: int = 3
    weights: str = "barycentric"
    dq_percentile: float = 99.9


PRT_COMPRESS_DEFAULTS = PrtCompressOptions()


def check_compress_options(o: PrtCompressOptions) -> None:
    if o.mode not in MODES:
        raise ValueError(f"prt: mode must be one of {MODES}, got {o.mode!r}")
    if o.weights not in WEIGHTS:
        raise ValueError(f"prt: weights must be one of {WEIGHTS}, got {o.weights!r}")
    if not 0 < o.reference_fraction <= 1:
        raise ValueError(f"prt: reference_fraction must be in (0, 1], got {o.reference_fraction}")
    if not 0 <= o.sh_order <= MAX_ORDER:
        raise ValueError(f"prt: sh_order must be in [0, {MAX_ORDER}], got {o.sh_order}")
    if not 50 <= o.dq_percentile <= 100:
        raise ValueError(f"prt: dq_percentile must be in [50, 100], got {o.dq_percentile}")


def compress_prt(q: np.ndarray, ds: DirectionSet, positions: np.ndarray, faces: np.ndarray, eta: float,
                 options: PrtCompressOptions = PRT_COMPRESS_DEFAULTS) -> PrtData:
    """Compress q.

    Parameters
    ----------
    q : (3, n, K) float64
        Scattering integrals at the surface vertices for the directions of `ds`.
    ds : DirectionSet
    positions : (n, 3) float64
    faces : (m, 3) int64
        The surface the reference points are chosen on.
    eta : float
    options : PrtCompressOptions
    """
    check_compress_options(options)
    q = np.asarray(q, dtype=np.float64)
    _, n, k = q.shape
    if k != ds.count or q.shape[0] != 3 or len(positions) != n:
        raise ValueError(f"prt: q must be (3, {len(positions)}, {ds.count}), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("prt: q has non-finite values")

    order = 0 if options.mode == "lloyd" else options.sh_order if options.mode == "refs+sh" else max(options.sh_order, 1)
    lut = np.zeros((3, 256))
    if options.mode == "sh":
        ref_vertices = np.zeros(0, dtype=np.int64)
        ref_triangles = np.zeros((0, 3), dtype=np.int64)
        vertex_triangle = np.zeros(n, dtype=np.int64)
        weight_codes = np.zeros((n, 2), dtype=np.int16)
        weight_scale = 1.0
        ref_codes = np.zeros((0, k, 3), dtype=np.uint8)
        base = np.zeros_like(q)
    else:
        if options.mode == "lloyd":
            ref_vertices = np.arange(n, dtype=np.int64)
            ref_triangles = np.repeat(ref_vertices[:, None], 3, axis=1)
            vertex_triangle = ref_vertices.copy()
            weights = np.tile([1.0, 0.0, 0.0], (n, 1))
        else:
            refs = reference_points(positions, faces, max(3, int(round(options.reference_fraction * n))))
            ref_vertices, ref_triangles, vertex_triangle, weights = (
                refs.ref_vertices, refs.triangles, refs.vertex_triangle, refs.weights)
        ref_codes = np.empty((len(ref_vertices), k, 3), dtype=np.uint8)
        q_ref = np.empty((3, len(ref_vertices), k))
        for c in range(3):
            levels, codes = lloyd_quantizer(q[c, ref_vertices, :])
            lut[c] = levels
            ref_codes[:, :, c] = codes
            q_ref[c] = levels[codes]
        if options.mode == "refs+sh" and options.weights == "least_squares":
            weights = least_squares_weights(q, q_ref, refs)
        weight_scale = float(max(1.0, np.ceil(np.abs(weights[:, :2]).max() * 4.0) / 4.0))
        weight_codes = np.round(np.clip(weights[:, :2] / weight_scale, -1.0, 1.0) * 32767.0).astype(np.int16)
        w = _weights(weight_codes, weight_scale)
        corners = ref_triangles[vertex_triangle]
        # Δq is taken against what the runtime reconstructs: quantised tables and weights.
        base = np.stack([_blend(w, q_ref[c], corners) for c in range(3)])

    c_count = order * order
    dq_codes = np.zeros((n, 3, c_count), dtype=np.int8)
    dq_scale = np.zeros((3, c_count))
    if c_count:
        coeffs = np.einsum("ij,cnj->nci", sh_fit_matrix(ds.directions, order), q - base)
        scale = np.percentile(np.abs(coeffs), options.dq_percentile, axis=0)
        dq_scale = np.where(scale > 0, scale, 1.0)
        dq_codes = np.round(np.clip(coeffs / dq_scale, -1.0, 1.0) * 127.0).astype(np.int8)

    return PrtData(
        directions=ds.directions.astype(np.float32),
        direction_triangles=ds.triangles.astype(np.int32),
        direction_inverse=ds.inverse.astype(np.float32),
        direction_lookup=ds.lookup.astype(np.int32),
        direction_neighbours=ds.neighbours.astype(np.int32),
        lut=lut.astype(np.float32),
        ref_vertices=ref_vertices,
        ref_codes=ref_codes,
        ref_triangles=ref_triangles.astype(np.int32),
        vertex_triangle=vertex_triangle.astype(np.int32),
        weight_codes=weight_codes,
        weight_scale=weight_scale,
        dq_codes=dq_codes,
        dq_scale=dq_scale.astype(np.float32),
        sh_order=order,
        eta=float(eta),
    )


def _weights(codes: np.ndarray, scale: float) -> np.ndarray:
    w01 = codes.astype(np.float64) / 32767.0 * scale
    return np.column_stack([w01, 1.0 - w01.sum(axis=1)])


def _blend(w: np.ndarray, table: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(n, K) Σ_k w[:, k] table[corners[:, k]] for one channel's (R, K) table, one corner at a time."""
    return sum(w[:, k:k + 1] * table[corners[:, k]] for k in range(3))


def decode_at_directions(prt: PrtData) -> np.ndarray:
    """(3, n, K) float64: q as the runtime reconstructs it at the set's own directions."""
    n, k = prt.vertex_count, len(prt.directions)
    out = np.zeros((3, n, k))
    if len(prt.ref_codes):
        w = _weights(prt.weight_codes, prt.weight_scale)
        corners = prt.ref_triangles[prt.vertex_triangle]
        lut = prt.lut.astype(np.float64)
        for c in range(3):
            out[c] = _blend(w, lut[c][prt.ref_codes[:, :, c]], corners)
    if prt.sh_order:
        basis = sh_basis(prt.directions.astype(np.float64), prt.sh_order)  # (K, C)
        coeffs = prt.dq_codes.astype(np.float64) / 127.0 * prt.dq_scale.astype(np.float64)[None]
        out += np.einsum("nci,ki->cnk", coeffs, basis)
    return out


def evaluate(prt: PrtData, omega: np.ndarray) -> np.ndarray:
    """(3, n) q at arbitrary light directions, interpolated as the GLSL runtime does.

    Parameters
    ----------
    omega : (3,) or (n, 3) float64
        One direction for all vertices (directional light) or one per vertex (point light).
    """
    n = prt.vertex_count
    omega = np.broadcast_to(np.asarray(omega, dtype=np.float64), (n, 3))
    ds = DirectionSet(prt.directions.astype(np.float64), prt.direction_triangles.astype(np.int64),
                      prt.direction_inverse.astype(np.float64), prt.direction_lookup, prt.direction_neighbours)
    index, beta = lookup_weights(ds, omega)
    out = np.zeros((3, n))
    if len(prt.ref_codes):
        w = _weights(prt.weight_codes, prt.weight_scale)
        corners = prt.ref_triangles[prt.vertex_triangle]
        for c in range(3):
            lut = prt.lut[c].astype(np.float64)
            for k in range(3):
                values = lut[prt.ref_codes[corners[:, k][:, None], index, c]]  # (n, 3 directions)
                out[c] += w[:, k] * np.einsum("na,na->n", beta, values)
    if prt.sh_order:
        basis = sh_basis(omega, prt.sh_order)  # (n, C)
        coeffs = prt.dq_codes.astype(np.float64) / 127.0 * prt.dq_scale.astype(np.float64)[None]
        out += np.einsum("nci,ni->cn", coeffs, basis)
    return out


def bytes_per_vertex(prt: PrtData) -> dict:
    """Every byte of the prt data per vertex as the glTF export stores it, tables amortised.

    ``_SSS_PRT_REF`` 4 B (2 × uint16), ``_SSS_PRT_W`` 4 B (2 × int16), ``_SSS_PRT_DQ*`` 3·C bytes
    padded to whole VEC4s; tables: reference codes R·K·3 B, reference triangles, directions, hull,
    lookup, LUT, Δq scales (as written: float32, uint32 indices).
    """
    n = max(prt.vertex_count, 1)
    per_vertex = {"_SSS_PRT_REF": 4.0, "_SSS_PRT_W": 4.0,
                  "_SSS_PRT_DQ": 4.0 * (-(-3 * prt.sh_order**2 // 4))}
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
    out = {**per_vertex, **{k: v / n for k, v in tables.items()}}
    out["total"] = float(sum(out.values()))
    return out
