"""prt compression and decoding: error falls with bytes spent, the baseline is the Lloyd tables,
the runtime's interpolation path, and the byte count."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.directions import direction_set, interpolation_weights
from sssbake.pipeline.core.sh import sh_basis, sh_fit_matrix
from sssbake.pipeline.core.surface import area_weighted_normals
from sssbake.pipeline.techniques.prt.compress import (
    SHARED_TABLES_ERROR,
    PrtCompressOptions,
    budget_reference_count,
    compress_prt,
    resolve_tables,
)
from sssbake.pipeline.techniques.prt.decode import (
    blend,
    bytes_per_vertex,
    decode_at_directions,
    decode_weights,
    evaluate,
    reference_detail,
)


def synthetic_q(positions, faces, directions, shadow=True):
    """(3, n, K) q-like field: clamped lobes about the vertex normal times a smooth tint, and a
    sharp cast-shadow edge (half the vertices lose the lights with ω_x < 0.2)."""
    normals = area_weighted_normals(positions, faces)
    cos = normals @ directions.T
    shape = 0.6 * np.clip(cos, 0.0, None) ** 1.3 + 0.25 * np.clip(0.4 + 0.6 * cos, 0.0, None) ** 2
    if shadow:
        shape = shape * np.where((positions[:, 1:2] > 0.0) & (directions[None, :, 0] < 0.2), 0.3, 1.0)
    tint = 0.5 + 0.15 * np.sin(2.0 * positions[:, :1]) + 0.1 * positions[:, 2:3]
    return np.stack([0.3 * shape * tint * (1.0 - 0.15 * c) for c in range(3)])


@pytest.fixture(scope="module")
def torus():
    t = trimesh.creation.torus(1.0, 0.4, major_sections=40, minor_sections=16)
    v, f = np.asarray(t.vertices, dtype=np.float64), np.asarray(t.faces, dtype=np.int64)
    ds = direction_set(48, lookup_size=16)
    return v, f, ds, synthetic_q(v, f, ds.directions)


def rms(prt, q):
    return float(np.sqrt(np.mean((decode_at_directions(prt) - q) ** 2)))


def test_error_falls_with_reference_points_and_sh_order(torus):
    v, f, ds, q = torus

    def run(**kw):
        return rms(compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(**kw)), q)

    # the paper's Fig. 6: SH alone, rising order (K = 48 holds order 6 at most)
    by_order = [run(mode="sh", sh_order=n) for n in (1, 2, 3, 4, 6)]
    assert all(b < a for a, b in zip(by_order, by_order[1:])), by_order
    # the paper's Fig. 9: more reference points, fixed n = 3; and more Δq orders at fixed refs
    by_refs = [run(reference_count=r, sh_order=3, weights="barycentric") for r in (20, 60, 180)]
    assert all(b < 0.9 * a for a, b in zip(by_refs, by_refs[1:])), by_refs
    by_dq = [run(reference_count=60, sh_order=n) for n in (0, 1, 2, 3, 4)]
    assert all(b < a for a, b in zip(by_dq, by_dq[1:])), by_dq
    # reference points carry what SH of the same order cannot, and fitted weights help
    assert by_refs[1] < 0.7 * by_order[2]
    assert run(reference_count=60, sh_order=0, weights="least_squares") < run(
        reference_count=60, sh_order=0, weights="barycentric")
    assert run(reference_count=60, sh_order=0, weights="best_fit") < run(
        reference_count=60, sh_order=0, weights="least_squares")
    # placing part of them where the fit is worst beats simplification alone at the same count (on
    # this uniform torus barely; see test_reference_points for a signal with a hard corner)
    assert run(reference_count=60, refine=0.6) < run(reference_count=60, refine=0.0)


def test_lloyd_mode_is_the_nearest_level_of_each_value(torus):
    v, f, ds, q = torus
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="lloyd"))
    assert prt.sh_order == 0 and len(prt.ref_codes) == len(v) and prt.weight_scale == 1.0
    decoded = decode_at_directions(prt)
    for c in range(3):
        lut = prt.lut[c].astype(np.float64)
        nearest = lut[np.abs(q[c][..., None] - lut).argmin(axis=-1)]
        np.testing.assert_allclose(np.abs(decoded[c] - q[c]), np.abs(nearest - q[c]), atol=1e-12)
    assert np.sqrt(np.mean((decoded - q) ** 2)) < 2e-3 * q.max()


def test_shared_tables_fit_at_least_as_well_as_the_best_rank_one_table(torus):
    v, f, ds, q = torus
    rng = np.random.default_rng(2)
    # channels proportional per vertex (colour × shape): shared tables lose only the Lloyd step
    separable = q[1:2] * rng.uniform(0.5, 1.5, (3, len(v), 1))
    # channels whose shapes differ: one a power of another (a wider or narrower lobe), or leaning
    powered = q[1:2] ** np.array([0.8, 1.0, 1.25])[:, None, None]
    mixed = q * (1.0 + 0.2 * np.arange(3)[:, None, None] * ds.directions[None, None, :, 2])
    options = PrtCompressOptions(reference_fraction=1.0, refine=0.0, detail_order=0, tables="shared")
    errors = {}
    for name, signal in (("separable", separable), ("powered", powered), ("mixed", mixed)):
        shared = compress_prt(signal, ds, v, f, 1.3, options)
        assert shared.ref_codes.shape == (len(v), 48, 1) and shared.ref_scale.shape == (len(v), 3)
        error = decode_at_directions(shared) - signal
        # least-squares colours: in every channel the error is orthogonal to that channel's shape
        shape = shared.lut.astype(np.float64)[:, shared.ref_codes[:, :, 0]]  # (3, n, K)
        np.testing.assert_allclose(np.einsum("cnk,cnk->cn", error, shape), 0.0, atol=1e-5 * signal.max() ** 2)
        rank_one = np.linalg.svd(np.transpose(signal, (1, 0, 2)), compute_uv=False)[:, 1:]
        floor = np.sqrt((rank_one**2).sum() / signal.size)  # the best one table times a colour
        rms = np.sqrt(np.mean(error**2))
        assert rms < floor + 2e-3 * signal.max(), (floor, rms)
        errors[name] = (floor / signal.max(), rms / signal.max())
    # per-channel levels of one code follow a monotone change of shape, which no rank-one table can
    floor, rms = errors["powered"]
    assert floor > 1e-2 and rms < 0.2 * floor, errors
    rgb = compress_prt(separable, ds, v, f, 1.3, replace(options, tables="rgb"))
    assert rgb.ref_codes.shape[2] == 3 and len(rgb.ref_scale) == 0 and rgb.detail_order == 0


def test_auto_tables_share_one_shape_unless_a_channel_gets_its_own_light_from_behind(torus):
    """`resolve_tables`: channels that differ by a colour (and a little in spread) share a table;
    a channel with its own back lobe (what `Material.back_gain` does to a thin part) gets RGB
    tables, and the compressed data follow the choice."""
    v, f, ds, q = torus
    options = PrtCompressOptions(reference_fraction=1.0, refine=0.0)
    assert options.tables == "auto"
    same = q[1:2] * np.array([1.0, 0.6, 0.3])[:, None, None]
    assert resolve_tables(same, "auto")[0] == "shared" and len(compress_prt(same, ds, v, f, 1.3, options).ref_scale)
    # blue 8 x as much from behind each vertex as the others (its lobe below the horizon)
    normals = trimesh.Trimesh(v, f).vertex_normals
    behind = (normals @ ds.directions.T < 0.0)[None]
    lobed = same * np.where(behind, np.array([1.0, 1.0, 8.0])[:, None, None], 1.0)
    tables, excess = resolve_tables(lobed, "auto")
    assert tables == "rgb" and excess[2] > SHARED_TABLES_ERROR > excess[0]
    prt = compress_prt(lobed, ds, v, f, 1.3, options)
    assert prt.ref_codes.shape[2] == 3 and len(prt.ref_scale) == 0
    assert resolve_tables(lobed, "shared") == ("shared", pytest.approx(np.zeros(3)))
    # a byte budget that holds shared tables but not RGB ones: the budget first
    budgets = np.arange(1.0, 400.0, 0.5)

    def fits(budget, tables):
        try:
            return budget_reference_count(budget, len(v), ds, 0, tables, 8) >= 3
        except ValueError:
            return False

    tight = next(b for b in budgets if fits(b, "shared"))
    assert not fits(tight, "rgb") and fits(tight, "auto")
    squeezed = compress_prt(lobed, ds, v, f, 1.3, replace(options, byte_budget=float(tight)))
    assert len(squeezed.ref_scale) and bytes_per_vertex(squeezed)["total"] <= tight


def test_detail_terms_reach_below_the_rank_one_floor(torus):
    v, f, ds, q = torus
    # channels whose lobes differ smoothly in direction: what one shape per point misses
    mixed = q * (1.0 + 0.4 * np.arange(3)[:, None, None] * ds.directions[None, None, :, 2])
    options = PrtCompressOptions(reference_fraction=1.0, refine=0.0, detail_order=0, tables="shared")
    plain = compress_prt(mixed, ds, v, f, 1.3, options)
    errors = []
    for order in (1, 2, 3):
        prt = compress_prt(mixed, ds, v, f, 1.3, replace(options, detail_order=order))
        assert prt.detail_codes.shape == (len(v), order * order) and prt.detail_colour.shape == (len(v), 3)
        errors.append(np.sqrt(np.mean((decode_at_directions(prt) - mixed) ** 2)))
        # the detail term is part of the table at every direction, and costs order² + 3 bytes per point
        extra = bytes_per_vertex(prt)["total"] - bytes_per_vertex(plain)["total"]
        assert extra == pytest.approx((len(v) * (order * order + 3) + 4 * order * order) / len(v))
        # at the set's own directions evaluate() (detail at ω itself) agrees with the tables
        np.testing.assert_allclose(evaluate(prt, ds.directions[7].astype(np.float64)),
                                   decode_at_directions(prt)[:, :, 7], rtol=1e-4, atol=1e-6 * mixed.max())
    floor = np.sqrt(np.mean((decode_at_directions(plain) - mixed) ** 2))
    assert errors[0] < floor and errors[2] < 0.5 * floor, (floor, errors)
    assert errors[1] <= errors[0] * 1.01 and errors[2] <= errors[1] * 1.01
    # orders above what K directions determine are lowered to what they do
    tiny = compress_prt(mixed[:, :, :9], direction_set(9), v, f, 1.3, replace(options, detail_order=4))
    assert tiny.detail_order == 3


def test_sh_codes_are_within_half_a_code_of_the_residual(torus):
    v, f, ds, q = torus
    for mode in ("sh", "refs+sh"):
        prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode=mode, reference_count=40, sh_order=3,
                                                                 dq_percentile=100))
        # What is left after decoding has, in each SH coefficient, at most half a code's worth.
        left = np.einsum("ij,cnj->nci", sh_fit_matrix(ds.directions, 3), q - decode_at_directions(prt))
        assert np.all(np.abs(left) <= prt.dq_scale.astype(np.float64) / 254.0 * (1 + 1e-4) + 1e-9)
    # least-error ranges clip a few outliers and code the rest finer: lower error overall
    mse = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(reference_count=40, sh_order=3))
    assert rms(mse, q) <= rms(prt, q)


def test_band_limited_q_is_coded_by_sh_alone(torus):
    v, f, ds, _ = torus
    coeffs = np.random.default_rng(0).normal(size=(3, len(v), 9)) * [1.0, 0.5, 0.2, 0.1, 0.1, 0.05, 0.05, 0.05, 0.02]
    q = coeffs @ sh_basis(ds.directions, 3).T
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="sh", sh_order=3, dq_percentile=100))
    assert len(prt.ref_codes) == 0 and not prt.weight_codes.any()
    step = prt.dq_scale.astype(np.float64) / 127.0  # (3, 9)
    decoded_coeffs = np.einsum("ij,cnj->cni", sh_fit_matrix(ds.directions, 3), decode_at_directions(prt))
    assert np.all(np.abs(decoded_coeffs - coeffs) <= step[:, None, :] / 2 * (1 + 1e-4) + 1e-9)


def test_evaluate_follows_the_runtime_interpolation(torus):
    v, f, ds, q = torus
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(reference_count=60, sh_order=2, weights="best_fit",
                                                            detail_order=4))
    decoded = decode_at_directions(prt)
    for j in (0, 17, 47):  # at the set's directions: the tables' own values
        np.testing.assert_allclose(evaluate(prt, ds.directions[j]), decoded[:, :, j], rtol=1e-5, atol=1e-7)
    # elsewhere: the exact hull interpolation of the reference part plus the SH part
    w = np.random.default_rng(1).normal(size=(len(v), 3))
    index, beta = interpolation_weights(ds, w)
    basis = sh_basis(w / np.linalg.norm(w, axis=1, keepdims=True), 2)
    coeffs = prt.dq_codes / 127.0 * prt.dq_scale.astype(np.float64)
    sh_part = np.einsum("nci,ni->cn", coeffs, basis)
    sh_at_set = np.einsum("nci,ki->cnk", coeffs, sh_basis(ds.directions, 2))
    # the reference points' detail terms are evaluated at ω itself, not interpolated
    assert prt.detail_order == 4
    weights = decode_weights(prt.weight_codes, prt.weight_scale, prt.weight_bits)
    corners = prt.ref_triangles[prt.vertex_triangle]
    detail = (prt.detail_codes, prt.detail_colour, prt.detail_scale, prt.detail_order)
    at_set = reference_detail(*detail, ds.directions)
    detail_at_set = np.stack([blend(weights, at_set[c], corners) for c in range(3)])
    at_w = reference_detail(*detail, w / np.linalg.norm(w, axis=1, keepdims=True))  # (3, R, n): column v for vertex v
    detail_part = sum(weights[:, k] * at_w[:, corners[:, k], np.arange(len(v))] for k in range(3))
    table_part = np.einsum("cnk,nk->cn", np.take_along_axis(decoded - sh_at_set - detail_at_set, index[None], axis=2),
                           beta)
    np.testing.assert_allclose(evaluate(prt, w), table_part + sh_part + detail_part, rtol=1e-5, atol=1e-7)
    # a subset of vertices
    some = np.array([3, 100, 5])
    np.testing.assert_allclose(evaluate(prt, w[some], vertices=some), (table_part + sh_part + detail_part)[:, some],
                               rtol=1e-5, atol=1e-7)


def test_bytes_per_vertex_matches_a_hand_count(torus):
    v, f, ds, q = torus
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(reference_count=40, sh_order=3, detail_order=4))
    n, k, r, fr = len(v), 48, len(prt.ref_codes), len(prt.ref_triangles)
    t = 2 * k - 4
    b = bytes_per_vertex(prt)
    # VEC3 float32: the triangle and both weight codes; 27 Δq codes -> 9 RGB triples
    assert prt.weight_bits == 8 and (b["_SSS_PRT_REF"], b["_SSS_PRT_DQ"]) == (12, 108)
    tables = (r * k              # shared reference codes, uint8
              + r * 3 * 4        # their colours, float32
              + fr * 3 * 2       # reference triangles, uint16
              + k * 3 * 4        # directions, float32
              + t * 3 * 2 * 2    # hull triangles and neighbours, uint16
              + t * 9 * 4        # inverses, float32
              + 16 * 16 * 2      # lookup, uint16
              + 3 * 256 * 4      # levels per channel, float32
              + 3 * 9 * 4        # Δq scales, float32
              + r * (16 + 3)     # detail codes (order 4) and colours, int8
              + 16 * 4)          # detail scales, float32
    assert b["total"] == pytest.approx(120 + tables / n)
    assert b["refCodes"] == pytest.approx(r * k / n)
    rgb = bytes_per_vertex(compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(reference_count=40, sh_order=3,
                                                                             tables="rgb", weight_bits=16)))
    assert rgb["refCodes"] == pytest.approx(r * k * 3 / n) and rgb["refScale"] == 0 and rgb["_SSS_PRT_REF"] == 12
    assert rgb["lut"] == pytest.approx(3 * 256 * 4 / n)
    sh_only = bytes_per_vertex(compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="sh", sh_order=1)))
    assert sh_only["_SSS_PRT_DQ"] == 12 and sh_only["refCodes"] == 0 and sh_only["refTriangles"] == 0


def test_weights_take_16_bits_beyond_65536_reference_triangles():
    # the uncompressed baseline has a reference triangle per vertex
    g = np.arange(257.0)
    v = np.column_stack([np.repeat(g, 257), np.tile(g, 257), np.zeros(257 * 257)])
    idx = np.arange(len(v)).reshape(257, 257)
    f = np.column_stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()])
    ds = direction_set(12, lookup_size=8)
    q = np.random.default_rng(0).integers(1, 5, (3, len(v), 12)) / 4.0  # few levels: a quick Lloyd fit
    big = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="lloyd"))
    assert len(big.ref_triangles) > 65536 and big.weight_bits == 16
    np.testing.assert_allclose(decode_at_directions(big), q)
    small = compress_prt(q[:, :65536], ds, v[:65536], f[f.max(axis=1) < 65536], 1.3, PrtCompressOptions(mode="lloyd"))
    assert small.weight_bits == 8 and small.vertex_triangle.max() == 65535
    np.testing.assert_allclose(decode_at_directions(small), q[:, :65536])


def test_a_byte_budget_sets_the_reference_count(torus):
    v, f, ds, q = torus
    for budget, order in ((48.0, 0), (104.0, 2)):
        prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(byte_budget=budget, sh_order=order, detail_order=4))
        total = bytes_per_vertex(prt)["total"]
        # one more point would not fit (a point: 48 codes, a colour, two uint16 triangles, 19 detail bytes)
        assert budget - (48 + 12 + 12 + 19) / len(v) < total <= budget, (budget, total)
    small = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(byte_budget=28.0))
    assert len(small.ref_codes) < len(prt.ref_codes)
    # 640 vertices: the fixed direction tables and _SSS_PRT_REF alone cost ~27 B/vertex
    with pytest.raises(ValueError, match="give at least"):
        compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(byte_budget=23.0))


def test_degenerate_signals_stay_finite(torus):
    v, f, ds, _ = torus
    for q in (np.zeros((3, len(v), 48)), np.full((3, len(v), 48), 0.2)):
        for options in (PrtCompressOptions(reference_count=30, sh_order=2, weights="best_fit"),
                        PrtCompressOptions(mode="sh", sh_order=2), PrtCompressOptions(mode="lloyd")):
            prt = compress_prt(q, ds, v, f, 1.3, options)
            assert all(np.all(np.isfinite(getattr(prt, name))) for name in ("lut", "dq_scale", "detail_scale"))
            np.testing.assert_allclose(decode_at_directions(prt), q, atol=1e-6)


def test_bad_input_is_refused(torus):
    v, f, ds, q = torus
    with pytest.raises(ValueError, match="mode must be one of"):
        compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="zip"))
    with pytest.raises(ValueError, match="q must be"):
        compress_prt(q[:, :10], ds, v, f, 1.3)
    with pytest.raises(ValueError, match="NaN"):
        compress_prt(np.where(q > 0.1, np.nan, q), ds, v, f, 1.3)
    with pytest.raises(ValueError, match="needs at least 49 directions"):
        compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="sh", sh_order=7))
    with pytest.raises(ValueError, match="needs sh_order >= 1"):
        compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="sh", sh_order=0))
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="sh", sh_order=1))
    with pytest.raises(ValueError, match="omega must be"):
        evaluate(prt, np.ones((2, 3)))


def test_reference_floor_keeps_small_meshes_dense():
    # 6.5 % of 642 vertices would be 42 points; the floor asks for 256 (and all of a smaller mesh).
    import trimesh

    from sssbake.pipeline.core.directions import direction_set
    from sssbake.pipeline.techniques.prt.compress import PrtCompressOptions, compress_prt
    m = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    x, f = np.asarray(m.vertices), np.asarray(m.faces)
    dirs = direction_set(24)
    q = np.clip(np.einsum("ij,kj->ik", x / 10.0, dirs.directions), 0.0, None)[None].repeat(3, axis=0) * 0.1
    for floor, expected in ((256, 256), (0, 42), (5000, 642)):
        prt = compress_prt(q, dirs, x, f, 1.3, PrtCompressOptions(reference_floor=floor))
        assert abs(len(prt.ref_vertices) - expected) <= 0.05 * expected + 3, (floor, len(prt.ref_vertices))


def test_float32_vertex_major_q_compresses_exactly_as_float64(torus):
    # precompute_prt's q: float32 (the gather's own rounding, so exact) in vertex-major memory
    # under the (3, n, K) view. The compression reads it in float64 pieces (`_dots`): every
    # choice (reference points, best-fit triangles, weights, tables) and the error must match
    # those from the same values as a float64 (3, n, K) array.
    v, f, ds, q = torus
    q32 = np.ascontiguousarray(q.astype(np.float32).transpose(1, 0, 2)).transpose(1, 0, 2)
    q64 = q32.astype(np.float64)
    options = PrtCompressOptions(reference_fraction=0.2, sh_order=2)
    a, b = compress_prt(q32, ds, v, f, 1.4, options), compress_prt(q64, ds, v, f, 1.4, options)
    for name in ("ref_vertices", "ref_triangles", "vertex_triangle", "weight_codes", "ref_codes", "dq_codes"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_allclose(a.ref_scale, b.ref_scale, rtol=1e-6)
    assert rms(a, q64) == pytest.approx(rms(b, q64), rel=1e-6)


def test_compression_error_in_chunks_is_the_whole_arrays(torus):
    from sssbake.pipeline.techniques.prt.stage import compression_error

    v, f, ds, q = torus
    prt = compress_prt(q, ds, v, f, 1.4, PrtCompressOptions(reference_fraction=0.2, sh_order=1))
    error = decode_at_directions(prt) - q
    squares, largest = compression_error(prt, q, chunk=97)  # chunks that do not divide n
    assert squares == pytest.approx(float(np.sum(error**2)), rel=1e-12)
    assert largest == float(np.abs(error).max())
    part = decode_at_directions(prt, slice(100, 300))
    np.testing.assert_array_equal(part, decode_at_directions(prt)[:, 100:300])


def test_compiled_blend_is_the_numpy_sum():
    # `blend` is compiled; the numpy definition it replaced, value for value
    rng = np.random.default_rng(6)
    table = rng.standard_normal((40, 13))
    w = rng.standard_normal((500, 3))
    corners = rng.integers(0, 40, (500, 3)).astype(np.int32)
    expected = sum(w[:, k:k + 1] * table[corners[:, k]] for k in range(3))
    assert np.array_equal(blend(w, table, corners), expected)
    assert blend(w[:0], table, corners[:0]).shape == (0, 13)
