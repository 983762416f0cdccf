"""prt compression: reference points, least-squares weights, Lloyd tables, SH of Δq, decoding."""

import numpy as np
import pytest

from sssbake.pipeline.prt_compress import (
    PrtCompressOptions,
    bytes_per_vertex,
    compress_prt,
    decode_at_directions,
    evaluate,
)
from sssbake.pipeline.reference_points import least_squares_weights, reference_points


def test_reference_points_attach_every_vertex(blob):
    v, f, _, _ = blob
    refs = reference_points(v, f, 100)
    assert 60 <= len(refs.ref_vertices) <= 140
    np.testing.assert_allclose(refs.weights.sum(axis=1), 1.0)
    assert np.all(refs.weights >= 0)
    # A reference point is its own weight-1 corner.
    corners = refs.ref_vertices[refs.triangles[refs.vertex_triangle]]
    own = np.isin(np.arange(len(v)), refs.ref_vertices)
    hit = corners[own][np.arange(own.sum()), refs.weights[own].argmax(axis=1)]
    np.testing.assert_array_equal(hit, np.flatnonzero(own))
    np.testing.assert_allclose(refs.weights[own].max(axis=1), 1.0, atol=1e-9)


def test_barycentric_weights_reproduce_linear_fields_on_a_plane():
    g = np.linspace(0.0, 1.0, 21)
    xx, yy = np.meshgrid(g, g)
    v = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    idx = np.arange(441).reshape(21, 21)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    refs = reference_points(v, faces, 40)
    field = 2.0 * v[:, 0] - 3.0 * v[:, 1] + 0.5
    corners = refs.ref_vertices[refs.triangles[refs.vertex_triangle]]
    error = np.abs((refs.weights * field[corners]).sum(axis=1) - field)
    # Exact wherever the vertex projects inside its triangle; only clamped vertices near the
    # simplified boundary (which moves inwards) may differ.
    assert np.mean(error < 1e-9) > 0.8
    interior = (np.abs(v[:, :2] - 0.5) < 0.3).all(axis=1)
    assert error[interior].max() < 1e-9


def test_least_squares_weights_never_fit_worse(blob):
    v, f, _, q = blob
    refs = reference_points(v, f, 80)
    q_ref = q[:, refs.ref_vertices, :]
    corners = refs.triangles[refs.vertex_triangle]

    def misfit(w):
        approx = sum(w[None, :, k, None] * q_ref[:, corners[:, k], :] for k in range(3))
        return ((q - approx) ** 2).sum(axis=(0, 2))

    lsq = least_squares_weights(q, q_ref, refs)
    np.testing.assert_allclose(lsq.sum(axis=1), 1.0)
    assert np.all(misfit(lsq) <= misfit(refs.weights) * (1 + 1e-9) + 1e-18)
    assert misfit(lsq).sum() < 0.9 * misfit(refs.weights).sum()


def test_lloyd_mode_reconstructs_within_the_tables(blob):
    v, f, ds, q = blob
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="lloyd"))
    decoded = decode_at_directions(prt)
    assert prt.sh_order == 0 and len(prt.ref_codes) == len(v)
    for c in range(3):
        # nearest-level quantisation: half the widest gap, or the distance past the outer levels
        levels = np.sort(prt.lut[c].astype(np.float64))
        worst = max(np.diff(levels).max() / 2, q[c].max() - levels[-1], levels[0] - q[c].min()) + 1e-6 * levels.max()
        assert np.abs(decoded[c] - q[c]).max() <= worst


def test_error_falls_with_sh_order_and_reference_points(blob):
    v, f, ds, q = blob

    def rms(options):
        return np.sqrt(np.mean((decode_at_directions(compress_prt(q, ds, v, f, 1.3, options)) - q) ** 2))

    by_order = [rms(PrtCompressOptions(mode="sh", sh_order=n, dq_percentile=100)) for n in (1, 2, 3, 5)]
    assert all(b < a for a, b in zip(by_order, by_order[1:])), by_order
    by_refs = [rms(PrtCompressOptions(reference_fraction=r, sh_order=2)) for r in (0.01, 0.05, 0.2)]
    assert all(b < a for a, b in zip(by_refs, by_refs[1:])), by_refs
    assert rms(PrtCompressOptions(sh_order=3)) < by_order[2]  # reference points beat SH alone


def test_evaluate_at_set_directions_equals_decode(blob):
    v, f, ds, q = blob
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(weights="least_squares"))
    decoded = decode_at_directions(prt)
    for j in (0, 17, 63):
        np.testing.assert_allclose(evaluate(prt, ds.directions[j]), decoded[:, :, j], rtol=1e-5, atol=1e-7)
    # per-vertex directions (a point light) work too
    per_vertex = np.repeat(ds.directions[5:6], len(v), axis=0)
    np.testing.assert_allclose(evaluate(prt, per_vertex), decoded[:, :, 5], rtol=1e-5, atol=1e-7)


def test_bytes_per_vertex_counts_every_block(blob):
    v, f, ds, q = blob
    prt = compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(reference_fraction=0.05, sh_order=3))
    b = bytes_per_vertex(prt)
    n, r, k = len(v), len(prt.ref_codes), len(ds.directions)
    assert b["_SSS_PRT_REF"] == 4 and b["_SSS_PRT_W"] == 4 and b["_SSS_PRT_DQ"] == 28  # 27 codes -> 7 VEC4
    assert b["refCodes"] == pytest.approx(r * k * 3 / n)
    assert b["total"] == pytest.approx(sum(val for key, val in b.items() if key != "total"))


def test_bad_options_are_refused(blob):
    v, f, ds, q = blob
    with pytest.raises(ValueError, match="mode must be one of"):
        compress_prt(q, ds, v, f, 1.3, PrtCompressOptions(mode="zip"))
    with pytest.raises(ValueError, match="q must be"):
        compress_prt(q[:, :10], ds, v, f, 1.3)
