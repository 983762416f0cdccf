"""prt compression (Hao & Varshney 2004 §4): reference points with Lloyd-quantised tables (per
channel, or one shared by the channels), and the remainder Δq as low-order spherical harmonics in
bytes. Produces `PrtData` (decoded by `prt_decode`); `benchmarks/bench_prt_compress.py` measures
the options on real q."""

from __future__ import annotations

from math import isqrt

import numpy as np

from sssbake.pipeline.core.directions import DirectionSet
from sssbake.pipeline.core.sh import MAX_ORDER, METHODS, sh_fit_matrix
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.decode import (
    blend,
    bytes_per_vertex,
    decode_at_directions,
    decode_int8,
    decode_weights,
    evaluate,
    reference_detail,
    reference_tables,
    weight_code_max,
)
from sssbake.pipeline.techniques.prt.lloyd import lloyd_quantizer
from sssbake.pipeline.techniques.prt.options import (
    MODES,
    PRT_COMPRESS_DEFAULTS,
    TABLES,
    WEIGHT_BITS,
    WEIGHTS,
    PrtCompressOptions,
)
from sssbake.pipeline.techniques.prt.reference_points import (
    best_fit_triangles,
    least_squares_weights,
    reference_points,
    refine_reference_points,
)

# The decoder lives in `prt_decode` and the options in `options`; their names are re-exported for
# existing callers.
__all__ = ["MODES", "WEIGHTS", "TABLES", "WEIGHT_BITS", "PRT_COMPRESS_DEFAULTS", "PrtCompressOptions",
           "check_compress_options", "compress_prt", "budget_reference_count", "rgb_tables", "shared_tables",
           "detail_tables",
           "int8_scales", "encode_int8", "decode_at_directions", "evaluate", "bytes_per_vertex"]

#: Reference triangles an 8-bit-weight vertex can address (16 bits of its attribute).
COMPACT_TRIANGLES = 65536
#: Levels of the reference tables' lookup table (`PrtData.lut` is (3, 256), codes uint8).
LUT_LEVELS = 256
#: Alternations of per-channel levels and colours in `shared_tables` (the first gives nearly all
#: the gain: benchmarks/README.md#prt-compression).
LUT_REFITS = 2
#: ``tables="auto"``: RGB tables where shared ones, fitted to a sample of vertices, miss a channel
#: by more than this share of its RMS over what RGB tables miss (their quantisation).
SHARED_TABLES_ERROR = 0.02
#: Vertices that sample.
TABLES_SAMPLE = 512
#: Candidate int8 ranges per Δq coefficient for ``dq_percentile=None``: the largest |coefficient|
#: times 2^(-i/4), i = 0..24 (down to 1/64 of it).
_SCALE_STEPS = 2.0 ** (-np.arange(25) / 4.0)


def check_compress_options(o: PrtCompressOptions) -> None:
    """Raise ValueError naming the first bad option."""
    if o.mode not in MODES:
        raise ValueError(f"prt compress: mode must be one of {MODES}, got {o.mode!r}")
    if o.weights not in WEIGHTS:
        raise ValueError(f"prt compress: weights must be one of {WEIGHTS}, got {o.weights!r}")
    if o.dq_percentile is not None and not 50 <= o.dq_percentile <= 100:
        raise ValueError(f"prt compress: dq_percentile must be in [50, 100] or None, got {o.dq_percentile}")
    if o.tables not in TABLES:
        raise ValueError(f"prt compress: tables must be one of {TABLES}, got {o.tables!r}")
    if o.sh_method not in METHODS:
        raise ValueError(f"prt compress: sh_method must be one of {METHODS}, got {o.sh_method!r}")
    if o.weight_bits not in WEIGHT_BITS:
        raise ValueError(f"prt compress: weight_bits must be one of {WEIGHT_BITS}, got {o.weight_bits}")
    if not 0 <= o.refine < 1:
        raise ValueError(f"prt compress: refine must be in [0, 1), got {o.refine}")
    if not 0 < o.reference_fraction <= 1:
        raise ValueError(f"prt compress: reference_fraction must be in (0, 1], got {o.reference_fraction}")
    if o.byte_budget is not None and not o.byte_budget > 0:
        raise ValueError(f"prt compress: byte_budget must be positive, got {o.byte_budget}")
    if o.reference_floor < 0:
        raise ValueError(f"prt compress: reference_floor must be >= 0, got {o.reference_floor}")
    if o.reference_count is not None and o.reference_count < 3:
        raise ValueError(f"prt compress: reference_count must be at least 3, got {o.reference_count}")
    if not 0 <= o.detail_order <= MAX_ORDER:
        raise ValueError(f"prt compress: detail_order must be in [0, {MAX_ORDER}], got {o.detail_order}")
    if not 0 <= o.sh_order <= MAX_ORDER:
        raise ValueError(f"prt compress: sh_order must be in [0, {MAX_ORDER}], got {o.sh_order}")
    if o.mode == "sh" and o.sh_order < 1:
        raise ValueError("prt compress: mode 'sh' needs sh_order >= 1 (it has no reference points)")


def compress_prt(q: np.ndarray, directions: DirectionSet, positions: np.ndarray, faces: np.ndarray, eta: float,
                 options: PrtCompressOptions = PRT_COMPRESS_DEFAULTS) -> PrtData:
    """Compress the scattering integrals of one mesh.

    Reference tables are Lloyd-quantised per channel; Δq is taken against what the runtime
    reconstructs (dequantised tables, quantised weights) so that it absorbs their coding error,
    then projected onto SH and coded in int8.

    Parameters
    ----------
    q : (3, n, K) float64 or float32
        Scattering integrals at the surface vertices for the directions of `directions`
        (a view of vertex-major memory, as `precompute_prt` gives, is read in place; any other
        layout is copied).
    directions : DirectionSet
    positions : (n, 3) float64
    faces : (m, 3) int64
        The surface the reference points are chosen on.
    eta : float
        Relative index of refraction (stored for the runtime's F_t).
    options : PrtCompressOptions

    Returns
    -------
    PrtData
    """
    check_compress_options(options)
    q = np.asarray(q)
    if q.dtype != np.float32:  # float32 q (`precompute_prt`'s, exact) is read as float64, not copied
        q = q.astype(np.float64, copy=False)
    positions = np.asarray(positions, dtype=np.float64)
    n = len(positions)
    k = len(directions.directions)
    if q.shape != (3, n, k):
        raise ValueError(f"prt compress: q must be (3, {n}, {k}) (channels, vertices, directions), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("prt compress: q has NaN or Inf values; check the precompute")
    # The fits read each vertex's (3, K) values as one row (`reference_points._vertex_rows`):
    # vertex-major memory, as `precompute_prt` gives (no copy); other layouts are copied once here.
    q = np.moveaxis(np.ascontiguousarray(np.moveaxis(q, 0, 1)), 0, 1)
    if not (np.isfinite(eta) and eta > 0):
        raise ValueError(f"prt compress: eta must be positive and finite, got {eta}")
    order = 0 if options.mode == "lloyd" else options.sh_order
    tables = resolve_tables(q, options.tables)[0] if options.mode == "refs+sh" else "rgb"
    # A detail order the direction count supports (tiny K would leave the fit underdetermined).
    detail_order = min(options.detail_order, isqrt(k)) if tables == "shared" else 0
    detail = (np.zeros((0, 0), dtype=np.int8), np.zeros((0, 3), dtype=np.int8), np.zeros(0, dtype=np.float32))
    if order * order > k:
        raise ValueError(f"prt compress: sh_order {order} needs at least {order * order} directions, got {k}; "
                         "lower sh_order")

    if options.mode == "sh":
        ref_vertices = np.zeros(0, dtype=np.int64)
        ref_triangles = np.zeros((0, 3), dtype=np.int64)
        vertex_triangle = np.zeros(n, dtype=np.int64)
        ref_codes = np.zeros((0, k, 3), dtype=np.uint8)
        ref_scale = np.zeros((0, 3), dtype=np.float32)
        lut = np.zeros((3, LUT_LEVELS), dtype=np.float32)
        weight_codes, weight_scale, bits = np.zeros((n, 2), dtype=np.int16), 1.0, options.weight_bits
    else:
        if options.mode == "lloyd":
            ref_vertices = np.arange(n, dtype=np.int64)
            ref_triangles = np.repeat(ref_vertices[:, None], 3, axis=1)
            vertex_triangle = ref_vertices.copy()
            weights = np.tile([1.0, 0.0, 0.0], (n, 1))
        else:
            if options.byte_budget is not None:
                try:
                    count = budget_reference_count(options.byte_budget, n, directions, order, tables,
                                                   options.weight_bits, detail_order)
                except ValueError:
                    if not (options.tables == "auto" and tables == "rgb"):
                        raise
                    tables = "shared"  # the budget first: RGB tables where they fit in it
                    detail_order = min(options.detail_order, isqrt(k))
                    count = budget_reference_count(options.byte_budget, n, directions, order, tables,
                                                   options.weight_bits, detail_order)
            else:
                count = options.reference_count or max(3, options.reference_floor,
                                                        int(round(options.reference_fraction * n)))
            count = min(n, count)
            refs = reference_points(positions, faces, max(3, int(round(count * (1.0 - options.refine)))))
            if options.refine:
                refs = refine_reference_points(positions, refs, q, count)
            ref_vertices, ref_triangles, vertex_triangle = refs.ref_vertices, refs.triangles, refs.vertex_triangle
            weights = refs.weights
        at_refs = q[:, ref_vertices].astype(np.float64)
        if tables == "shared":
            ref_codes, lut, ref_scale = shared_tables(at_refs)
        else:
            ref_codes, lut, ref_scale = rgb_tables(at_refs)
        q_ref = reference_tables(ref_codes, lut, ref_scale)
        if detail_order:
            detail = detail_tables(at_refs - q_ref, directions.directions, detail_order)
            q_ref += reference_detail(*detail, detail_order, directions.directions)
        if options.mode == "refs+sh" and options.weights == "least_squares":
            weights = least_squares_weights(q, q_ref, refs)
        elif options.mode == "refs+sh" and options.weights == "best_fit":
            fitted = best_fit_triangles(q, q_ref, refs)
            vertex_triangle, weights = fitted.vertex_triangle, fitted.weights
        # Barycentric weights need scale 1; fitted ones the next quarter above their largest |w|.
        weight_scale = float(max(1.0, np.ceil(np.abs(weights[:, :2]).max() * 4.0) / 4.0))
        bits = 8 if options.weight_bits == 8 and len(ref_triangles) <= COMPACT_TRIANGLES else 16
        top = weight_code_max(bits)
        weight_codes = np.round(np.clip(weights[:, :2] / weight_scale, -1.0, 1.0) * top).astype(np.int16)

    count = order * order
    dq_codes = np.zeros((n, 3, count), dtype=np.int8)
    dq_scale = np.zeros((3, count), dtype=np.float32)
    if count:
        residual = q
        if options.mode != "sh":
            w = decode_weights(weight_codes, weight_scale, bits)
            corners = ref_triangles[vertex_triangle]
            residual = np.stack([q[c] - blend(w, q_ref[c], corners) for c in range(3)])
        coeffs = np.einsum("ij,cnj->nci", sh_fit_matrix(directions.directions, order, options.sh_method), residual)
        dq_scale = int8_scales(coeffs, options.dq_percentile)
        dq_codes = encode_int8(coeffs, dq_scale)

    return PrtData(
        directions=directions.directions.astype(np.float32),
        direction_triangles=directions.triangles.astype(np.int32),
        direction_inverse=directions.inverse.astype(np.float32),
        direction_lookup=directions.lookup.astype(np.int32),
        direction_neighbours=directions.neighbours.astype(np.int32),
        lut=lut,
        ref_vertices=ref_vertices.astype(np.int64),
        ref_codes=ref_codes,
        ref_scale=ref_scale,
        ref_triangles=ref_triangles.astype(np.int32),
        vertex_triangle=vertex_triangle.astype(np.int32),
        weight_codes=weight_codes,
        weight_scale=weight_scale,
        weight_bits=bits,
        dq_codes=dq_codes,
        dq_scale=dq_scale,
        sh_order=order,
        eta=float(eta),
        detail_order=detail_order,
        detail_codes=detail[0],
        detail_colour=detail[1],
        detail_scale=detail[2],
    )


def budget_reference_count(budget: float, n: int, directions: DirectionSet, sh_order: int, tables: str,
                           weight_bits: int, detail_order: int = 0) -> int:
    """The most reference points whose data stays within `budget` bytes per vertex.

    Counts as `bytes_per_vertex` does, with two reference triangles per point (simplifying a
    closed surface gives 2R - 4, each refinement adds two) and 16-bit weights once those
    triangles pass what 8-bit ones address.

    Parameters
    ----------
    budget : float
        Bytes per vertex.
    n : int
        Surface vertices.
    directions : DirectionSet
    sh_order : int
    tables : str
        ``"shared"`` or ``"rgb"``; ``"auto"`` (see `PrtCompressOptions`) counts as shared, the
        cheaper: `compress_prt` falls back to shared tables where RGB ones do not fit the budget.
    weight_bits : int
    detail_order : int
        Of the shared tables' detail terms (order² + 3 bytes per point, order² scales).

    Returns
    -------
    int
        At least 3; ValueError when even 3 reference points do not fit.
    """
    channels = 3 if tables == "rgb" else 1
    k, c = len(directions.directions), sh_order * sh_order
    detail = detail_order * detail_order if channels == 1 else 0
    # codes, colour, uint16 triangles, detail codes and colour
    per_point = k * channels + (12 if channels == 1 else 0) + 2 * 3 * 2 + (detail + 3 if detail else 0)

    def fixed(bits):  # everything but the reference points, in bytes
        bare = PrtData(
            directions=directions.directions, direction_triangles=directions.triangles,
            direction_inverse=directions.inverse, direction_lookup=directions.lookup,
            direction_neighbours=directions.neighbours, lut=np.zeros((3, LUT_LEVELS), np.float32),
            ref_vertices=np.zeros(0, np.int64), ref_codes=np.zeros((0, k, channels), np.uint8),
            ref_scale=np.zeros((0, 3), np.float32), ref_triangles=np.zeros((0, 3), np.int32),
            vertex_triangle=np.zeros(n, np.int32), weight_codes=np.zeros((n, 2), np.int16), weight_scale=1.0,
            weight_bits=bits, dq_codes=np.zeros((n, 3, c), np.int8), dq_scale=np.zeros((3, c), np.float32),
            sh_order=sh_order, eta=1.0, detail_order=detail_order if detail else 0,
            detail_scale=np.zeros(detail, np.float32))
        return bytes_per_vertex(bare)["total"] * n

    count = int((budget * n - fixed(weight_bits)) // per_point)
    if weight_bits == 8 and 2 * count > COMPACT_TRIANGLES:
        count = int((budget * n - fixed(16)) // per_point)
    if count < 3:
        least = (fixed(weight_bits) + 3 * per_point) / n
        raise ValueError(f"prt compress: a byte budget of {budget} B/vertex holds no 3 reference points on "
                         f"{n} vertices; give at least {least:.1f}")
    return count


def rgb_tables(q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The paper's reference tables: each channel Lloyd-quantised with its own LUT.

    Parameters
    ----------
    q_ref : (3, R, K) float64

    Returns
    -------
    codes : (R, K, 3) uint8
    lut : (3, 256) float32
    scale : (0, 3) float32
        No colours (see `PrtData.ref_scale`).
    """
    codes = np.empty((q_ref.shape[1], q_ref.shape[2], 3), dtype=np.uint8)
    lut = np.empty((3, LUT_LEVELS), dtype=np.float32)
    for c in range(3):
        lut[c], codes[:, :, c] = lloyd_quantizer(q_ref[c], levels=LUT_LEVELS)
    return codes, lut, np.zeros((0, 3), dtype=np.float32)


def shared_tables(q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One table of codes per reference point for all three channels:
    q_c(ω) ≈ colour_c · lut_c[code(ω)].

    The shape is the leading right singular vector of the point's (3, K) table (non-negative for
    a non-negative table), scaled to peak 1 and Lloyd-quantised with one set of levels over all
    points. Then each channel gets its own levels for the same codes (the least-squares level of
    every code given the colours) and the colours are refitted, `LUT_REFITS` times: the
    channels' shapes differ in ways the codes order alike (a wider blur in red than in blue),
    which per-channel levels follow at no per-point byte. A third of the bytes of RGB tables, at
    an error below 1 % of the largest q, so the bytes buy ~2.7x the reference points instead
    (benchmarks/README.md#prt-compression).

    Parameters
    ----------
    q_ref : (3, R, K) float64

    Returns
    -------
    codes : (R, K, 1) uint8
    lut : (3, 256) float32
        Per channel, the level of each code (unitless: the colours carry the scale).
    scale : (R, 3) float32
        The colours (1/sr), least-squares for the float32 levels.
    """
    x = np.transpose(q_ref, (1, 0, 2))  # (R, 3, K)
    shape = np.linalg.svd(x, full_matrices=False)[2][:, 0, :]
    shape *= np.where(shape.sum(axis=1, keepdims=True) < 0.0, -1.0, 1.0)  # the SVD's sign is arbitrary
    peak = shape.max(axis=1, keepdims=True)
    shape = np.clip(shape / np.where(peak > 0.0, peak, 1.0), 0.0, 1.0)

    def fit_colour(levels):  # (R, 3) least-squares colour per point and channel for (3, 256) levels
        read = levels[:, codes]  # (3, R, K)
        norm = (read * read).sum(axis=2).T
        return np.einsum("rck,crk->rc", x, read) / np.where(norm > 0.0, norm, 1.0)

    # Weighted by the colour's energy, the levels minimise the error of q rather than of the shape.
    norm = (shape * shape).sum(axis=1)
    energy = ((np.einsum("rck,rk->rc", x, shape) / np.where(norm > 0.0, norm, 1.0)[:, None]) ** 2).sum(axis=1)
    energy += np.finfo(np.float64).tiny  # all-black q: uniform weights
    levels, codes = lloyd_quantizer(shape, levels=LUT_LEVELS, weights=np.broadcast_to(energy[:, None], shape.shape))
    lut = np.tile(levels, (3, 1))
    colour = fit_colour(lut)
    for _ in range(LUT_REFITS):
        for c in range(3):
            w = np.broadcast_to(colour[:, c:c + 1], codes.shape).ravel()
            num = np.bincount(codes.ravel(), w * x[:, c].ravel(), LUT_LEVELS)
            den = np.bincount(codes.ravel(), w * w, LUT_LEVELS)
            lut[c] = np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), lut[c])  # unused codes keep theirs
        colour = fit_colour(lut)
    lut = lut.astype(np.float32)
    return codes[:, :, None], lut, fit_colour(lut.astype(np.float64)).astype(np.float32)


def detail_tables(residual: np.ndarray, directions: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each reference point's detail term: the leading (colour, shape) pair of what its shared
    table misses, the shape as SH of `order` in int8, the colour as an int8 unit vector.

    The miss is mostly rank one: the channels' shadow edges differ by a blur
    (benchmarks/README.md#prt-compression).

    Parameters
    ----------
    residual : (3, R, K) float64
        q at the reference points minus their decoded shared tables.
    directions : (K, 3) float64
    order : int

    Returns
    -------
    codes : (R, order²) int8
    colour : (R, 3) int8
    scale : (order²,) float32
    """
    x = np.transpose(residual, (1, 0, 2))  # (R, 3, K)
    u, s, vt = np.linalg.svd(x, full_matrices=False)
    shape = vt[:, 0, :] * s[:, :1]  # (R, K)
    colour = u[:, :, 0]
    flip = np.where(colour.sum(axis=1) < 0.0, -1.0, 1.0)[:, None]  # the SVD's sign is arbitrary
    colour, shape = colour * flip, shape * flip
    coeffs = shape @ sh_fit_matrix(np.asarray(directions, dtype=np.float64), order, "lsq").T  # (R, D)
    scale = int8_scales(coeffs[:, None, :])[0]
    return encode_int8(coeffs[:, None, :], scale[None])[:, 0], np.round(colour * 127.0).astype(np.int8), scale


def int8_scales(coeffs: np.ndarray, percentile: float | None = None) -> np.ndarray:
    """(3, C) float32 value of code 127 per channel and coefficient of `coeffs` (n, 3, C).

    A number: that percentile of |coefficient| (100: the largest, nothing clips). None: of the
    candidate ranges max · 2^(-i/4), the one whose rounding-plus-clipping error summed over the
    vertices is least: the residual's tails are heavy, so clipping them costs more than coarser
    steps (benchmarks/README.md#prt-compression). A range
    of 0 is stored as 1 (all codes 0).
    """
    magnitude = np.abs(coeffs)
    if percentile is not None:
        return _stored_scale(np.percentile(magnitude, percentile, axis=0))
    candidates = _stored_scale(magnitude.max(axis=0)[None] * _SCALE_STEPS[:, None, None])  # (S, 3, C)
    error = np.stack([((coeffs - decode_int8(encode_int8(coeffs, s), s)) ** 2).sum(axis=0) for s in candidates])
    return np.take_along_axis(candidates, error.argmin(axis=0)[None], axis=0)[0]


def _stored_scale(scale: np.ndarray) -> np.ndarray:
    """`scale` as float32; a range that is 0, or below float32's (coefficients under 1e-38, which
    decode to 0 either way), is stored as 1 with codes 0."""
    stored = np.asarray(scale, dtype=np.float64).astype(np.float32)
    return np.where(stored >= np.finfo(np.float32).tiny, stored, np.float32(1.0))


def encode_int8(coeffs: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(n, 3, C) int8 codes round(127 · coeffs / scale), clipped to ±127."""
    return np.round(np.clip(coeffs / scale.astype(np.float64), -1.0, 1.0) * 127.0).astype(np.int8)


def resolve_tables(q: np.ndarray, tables: str, seed: int = 0) -> tuple[str, np.ndarray]:
    """The reference tables ``tables="auto"`` stands for on `q` (3, n, K), and the shared tables'
    excess error per channel that chose them ((3,) float64; zeros when `tables` was given).

    Shared tables hold one directional shape per reference point for all channels; they are a
    third of the bytes and as good where the channels' shapes differ only in how far they blur.
    Where an object lets different shares of each channel through from behind
    (`Material.back_gain`: a thin skin1 part lets blue through 4-5 x more than red, relative to the
    profile) the shapes differ in kind and one shape per point cannot follow them (a 1 mm skin1
    leaf: object RMSE 0.089 against the reference with shared tables, 0.019 with RGB; best-fit
    Lambert 0.038). So both are fitted to `TABLES_SAMPLE` vertices' tables and RGB is chosen when
    the shared ones miss some channel by `SHARED_TABLES_ERROR` of its RMS more.
    """
    if tables != "auto":
        return tables, np.zeros(3)
    n = q.shape[1]
    sample = np.sort(np.random.default_rng(seed).choice(n, min(n, TABLES_SAMPLE), replace=False))
    at = np.asarray(q[:, sample], dtype=np.float64)
    size = np.sqrt(np.mean(at * at, axis=(1, 2)))

    def miss(fitted):
        return np.sqrt(np.mean((reference_tables(*fitted) - at) ** 2, axis=(1, 2))) / np.maximum(size, 1e-300)

    excess = miss(shared_tables(at)) - miss(rgb_tables(at))
    return ("rgb" if excess.max() > SHARED_TABLES_ERROR else "shared"), excess
