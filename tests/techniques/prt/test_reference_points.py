"""Reference points: every vertex on a simplified triangle, exact barycentrics, fitted weights."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.directions import fibonacci_sphere
from sssbake.pipeline.core.surface import area_weighted_normals
from sssbake.pipeline.mesh.simplify import Simplified
from sssbake.pipeline.techniques.prt.reference_points import (
    INSIDE_EPS,
    attach_vertices,
    best_fit_triangles,
    closest_point_barycentrics,
    least_squares_weights,
    reference_points,
    refine_reference_points,
)


def lobe_q(positions, faces, directions):
    """(3, n, K) q-like field: clamped cosine lobes about the vertex normal, colour varying smoothly."""
    normals = area_weighted_normals(positions, faces)
    cos = normals @ directions.T
    shape = 0.7 * np.clip(cos, 0.0, None) ** 1.2 + 0.3 * np.clip(0.5 + 0.5 * cos, 0.0, None) ** 2
    tint = 0.4 + 0.1 * np.sin(2.0 * positions[:, :1]) + 0.05 * positions[:, 1:2]
    return np.stack([shape * (tint + 0.05 * c) for c in range(3)])


@pytest.fixture(scope="module")
def torus():
    t = trimesh.creation.torus(1.0, 0.35, major_sections=48, minor_sections=16)
    return np.asarray(t.vertices, dtype=np.float64), np.asarray(t.faces, dtype=np.int64)


@pytest.fixture(scope="module")
def grid():
    g = np.linspace(0.0, 1.0, 21)
    xx, yy = np.meshgrid(g, g)
    v = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    idx = np.arange(v.shape[0]).reshape(21, 21)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    return v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def test_every_vertex_gets_a_triangle_and_reference_points_weight_one(torus):
    v, f = torus
    refs = reference_points(v, f, 60)
    assert 50 <= len(refs.ref_vertices) <= 70
    assert len(np.unique(refs.ref_vertices)) == len(refs.ref_vertices)
    assert refs.vertex_triangle.min() >= 0 and refs.vertex_triangle.max() < len(refs.triangles)
    np.testing.assert_allclose(refs.weights.sum(axis=1), 1.0, atol=1e-12)
    assert refs.weights.min() >= 0.0
    corners = refs.ref_vertices[refs.triangles[refs.vertex_triangle]]
    own = corners[refs.ref_vertices] == refs.ref_vertices[:, None]
    assert np.all(own.sum(axis=1) == 1)
    np.testing.assert_array_equal(refs.weights[refs.ref_vertices], own.astype(np.float64))
    # Every vertex is close to its triangle: within a few simplified edge lengths of the torus.
    p = (refs.weights[:, :, None] * v[corners]).sum(axis=1)
    edge = np.linalg.norm(v[corners[:, 0]] - v[corners[:, 1]], axis=1).mean()
    assert np.linalg.norm(p - v, axis=1).max() < 0.5 * edge


def test_barycentric_weights_reproduce_linear_fields_on_a_plane(grid):
    v, f = grid
    refs = reference_points(v, f, 30)
    corners = refs.ref_vertices[refs.triangles[refs.vertex_triangle]]
    _, distance, inside = closest_point_barycentrics(v, v[corners])
    assert inside.mean() > 0.85 and np.all(distance[inside] < 1e-12)
    for field in (2.0 * v[:, 0] - 3.0 * v[:, 1] + 0.5, v[:, 1]):
        approx = (refs.weights * field[corners]).sum(axis=1)
        np.testing.assert_allclose(approx[inside], field[inside], atol=1e-12)


def test_closest_point_matches_a_dense_search():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(80, 3, 3))
    tri[0] = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]  # degenerate: a segment
    p = rng.normal(size=(80, 3)) * 1.5
    bary, distance, inside = closest_point_barycentrics(p, tri)
    np.testing.assert_allclose(bary.sum(axis=1), 1.0)
    assert bary.min() >= 0.0 and not inside[0]
    np.testing.assert_allclose(np.linalg.norm(np.einsum("mk,mkj->mj", bary, tri) - p, axis=1), distance, atol=1e-12)
    s, t = np.meshgrid(np.linspace(0, 1, 301), np.linspace(0, 1, 301))
    keep = s + t <= 1
    samples = np.column_stack([1 - s[keep] - t[keep], s[keep], t[keep]])  # (S, 3) barycentrics
    points = np.einsum("sk,mkj->msj", samples, tri)
    dense = np.linalg.norm(points - p[:, None], axis=2).min(axis=1)
    assert np.all(distance <= dense + 1e-12) and np.all(dense - distance < 5e-3 * (1 + dense))


def test_vertices_outside_their_parents_triangles_find_the_containing_one(grid):
    v, f = grid
    kept = np.array([0, 20, 440, 420])  # the four corners of the unit square
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    collapse = np.zeros(len(v), dtype=np.int64)  # every vertex says: the corner (0, 0) is my parent
    collapse[kept] = np.arange(4)
    simple = Simplified(v[kept], faces, collapse, kept)
    refs = attach_vertices(v, f, simple)
    # Vertices above the diagonal are in triangle 1 only; both triangles touch corner 0.
    upper = v[:, 1] > v[:, 0] + 1e-9
    assert np.all(refs.vertex_triangle[upper] == 1) and np.all(refs.vertex_triangle[v[:, 1] < v[:, 0] - 1e-9] == 0)
    field = 1.0 + v[:, 0] + 2.0 * v[:, 1]
    corners = kept[faces[refs.vertex_triangle]]
    np.testing.assert_allclose((refs.weights * field[corners]).sum(axis=1), field, atol=1e-12)

    # Parent (0, 1) touches triangle 1 only: vertices below the diagonal lie outside all of their
    # parent's triangles, and the nearest-triangle search must find triangle 0 for them.
    collapse[:] = 3
    collapse[kept] = np.arange(4)
    refs = attach_vertices(v, f, Simplified(v[kept], faces, collapse, kept))
    assert np.all(refs.vertex_triangle[v[:, 1] < v[:, 0] - 1e-9] == 0)
    corners = kept[faces[refs.vertex_triangle]]
    np.testing.assert_allclose((refs.weights * field[corners]).sum(axis=1), field, atol=1e-12)

    # With triangle 0 gone they are clamped onto the diagonal edge, not extrapolated.
    refs = attach_vertices(v, f, Simplified(v[kept], faces[1:], collapse, kept))
    np.testing.assert_array_equal(refs.vertex_triangle, 0)
    assert refs.weights.min() >= 0.0
    below = v[:, 1] < v[:, 0] - 1e-9
    np.testing.assert_allclose(refs.weights[below, 2], 0.0)  # no weight on the far corner (0, 1)


def test_the_fallback_search_keeps_vertices_on_their_own_side_of_a_thin_slab():
    # Top sheet (facing +z) at z = 0.01 with a centre vertex dipped to z = 0.003, bottom sheet (facing
    # -z) at z = 0; the centre vertex lost its parent and is nearer to the bottom triangles.
    top = np.array([[0, 0, 0.01], [1, 0, 0.01], [1, 1, 0.01], [0, 1, 0.01], [0.5, 0.5, 0.003]])
    bottom = top[:4] * [1, 1, 0]
    v = np.concatenate([top, bottom])
    f = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [5, 7, 6], [5, 8, 7]])
    kept = np.array([0, 1, 2, 3, 5, 6, 7, 8])
    collapse = np.full(len(v), -1)
    collapse[kept] = np.arange(8)
    simple = Simplified(v[kept], np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]]), collapse, kept)
    refs = attach_vertices(v, f, simple)
    assert refs.vertex_triangle[4] in (0, 1)
    np.testing.assert_allclose(refs.weights[4] @ v[kept[simple.faces[refs.vertex_triangle[4]]]], [0.5, 0.5, 0.01])


def test_least_squares_weights_never_fit_worse_and_fall_back_when_ill_posed(torus):
    v, f = torus
    d = fibonacci_sphere(48)
    q = lobe_q(v, f, d)
    refs = reference_points(v, f, 40)
    q_ref = q[:, refs.ref_vertices]
    corners = refs.triangles[refs.vertex_triangle]

    def misfit(w, tri=corners):
        approx = sum(w[None, :, k, None] * q_ref[:, tri[:, k], :] for k in range(3))
        return ((q - approx) ** 2).sum(axis=(0, 2))

    lsq = least_squares_weights(q, q_ref, refs)
    np.testing.assert_allclose(lsq.sum(axis=1), 1.0, atol=1e-12)
    assert np.abs(lsq[:, :2]).max() <= 4.0
    assert np.all(misfit(lsq) <= misfit(refs.weights) * (1 + 1e-9) + 1e-15)
    assert misfit(lsq).sum() < 0.7 * misfit(refs.weights).sum()
    np.testing.assert_array_equal(lsq[refs.ref_vertices], refs.weights[refs.ref_vertices])

    # References carrying one and the same signal: nothing to fit, barycentric weights stay.
    flat = np.broadcast_to(q[:, :1], q.shape)
    same = least_squares_weights(flat, flat[:, refs.ref_vertices], refs)
    np.testing.assert_allclose(same, refs.weights, atol=1e-12)
    assert np.all(np.isfinite(same))

    best = best_fit_triangles(q, q_ref, refs)
    best_corners = best.triangles[best.vertex_triangle]
    np.testing.assert_allclose(best.weights.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(misfit(best.weights, best_corners) <= misfit(lsq) * (1 + 1e-9) + 1e-15)
    assert misfit(best.weights, best_corners).sum() < 0.9 * misfit(lsq).sum()
    np.testing.assert_array_equal(best.vertex_triangle[refs.ref_vertices], refs.vertex_triangle[refs.ref_vertices])
    # every new triangle shares a corner with the geometric one
    shared = (best_corners[:, :, None] == corners[:, None, :]).any(axis=(1, 2))
    assert np.all(shared)


def test_refinement_adds_points_where_the_fit_is_worst(grid):
    v, f = grid
    d = fibonacci_sphere(32)
    # smooth everywhere but a sharp lobe that swings across the corner x, y > 0.7
    tilt = np.clip((v[:, :1] - 0.7) * (v[:, 1:2] - 0.7) * 40.0, 0.0, 1.0) * (v[:, :1] > 0.7) * (v[:, 1:2] > 0.7)
    lobe = np.clip(d[None, :, 2] * (1.0 - tilt) + d[None, :, 0] * tilt, 0.0, None) ** 4
    q = np.stack([lobe * (1.0 + 0.1 * c) + 0.05 * v[:, :1] for c in range(3)])
    start = reference_points(v, f, 20)
    refs = refine_reference_points(v, start, q, 45)
    r0 = len(start.ref_vertices)
    assert len(refs.ref_vertices) == 45 and len(np.unique(refs.ref_vertices)) == 45
    np.testing.assert_array_equal(refs.ref_vertices[:r0], start.ref_vertices)
    # splitting 1-to-3 adds two triangles per point; every vertex on a triangle, weight 1 at references
    assert len(refs.triangles) == len(start.triangles) + 2 * (45 - r0)
    np.testing.assert_allclose(refs.weights.sum(axis=1), 1.0, atol=1e-12)
    assert refs.weights.min() >= 0.0
    corners = refs.ref_vertices[refs.triangles[refs.vertex_triangle]]
    own = corners[refs.ref_vertices] == refs.ref_vertices[:, None]
    np.testing.assert_array_equal(refs.weights[refs.ref_vertices], own.astype(np.float64))
    # the positions are reproduced on the plane: the split triangles are a triangulation
    p = np.einsum("nk,nkj->nj", refs.weights, v[corners])
    inside = np.linalg.norm(p - v, axis=1) < 1e-12
    assert inside.mean() > 0.95
    # the new points crowd into the corner whose signal the start fitted worst (16 % of the area)
    added = v[refs.ref_vertices[r0:]]
    assert np.mean((added[:, 0] > 0.6) & (added[:, 1] > 0.6)) > 0.7

    def misfit(r):
        q_ref = q[:, r.ref_vertices]
        fit = best_fit_triangles(q, q_ref, r)
        tri = fit.triangles[fit.vertex_triangle]
        approx = sum(fit.weights[None, :, k, None] * q_ref[:, tri[:, k], :] for k in range(3))
        return ((q - approx) ** 2).sum()

    assert misfit(refs) < 0.1 * misfit(reference_points(v, f, 45))


def test_bad_input_is_refused(torus):
    v, f = torus
    with pytest.raises(ValueError, match="at least 3"):
        reference_points(v, f, 2)
    refs = reference_points(v, f, 40)
    with pytest.raises(ValueError, match="q must be"):
        least_squares_weights(np.zeros((3, 5, 8)), np.zeros((3, 5, 8)), refs)


def test_fit_inner_products_of_float32_signals_are_float64_sums():
    # `_fit`'s misfit is |q|² - 2 b·w + wᵀGw: it cancels to ~1e-7 of |q|² for a good fit, so its
    # inner products must be float64 sums even of float32 q (a float32 sum errs by ~1e-7).
    from sssbake.pipeline.techniques.prt.reference_points import _dots, _vertex_rows

    rng = np.random.default_rng(3)
    q = rng.random((3, 500, 200)).astype(np.float32)
    i, j = rng.integers(0, 500, 2000), rng.integers(0, 500, 2000)
    exact = np.einsum("cik,cik->i", q[:, i].astype(np.float64), q[:, j].astype(np.float64))
    vertex_major = np.ascontiguousarray(_vertex_rows(q))
    np.testing.assert_allclose(_dots(vertex_major, i, vertex_major, j), exact, rtol=1e-13)
    np.testing.assert_allclose(_dots(_vertex_rows(q), i, _vertex_rows(q.astype(np.float64)), j), exact, rtol=1e-13)


def test_fit_inner_products_on_threads_equal_the_serial_sums(monkeypatch):
    # blocks summed on threads write their own slices: the same sums, bit for bit
    from sssbake.pipeline.techniques.prt import reference_points as rp

    rng = np.random.default_rng(4)
    rows = rp._vertex_rows(rng.random((3, 400, 20)).astype(np.float32))
    i, j = rng.integers(0, 400, 5000), rng.integers(0, 400, 5000)
    monkeypatch.setattr(rp, "DOT_PAIRS", 37)
    monkeypatch.setattr(rp, "THREADS", 1)
    serial = rp._dots(rows, i, rows, j)
    monkeypatch.setattr(rp, "THREADS", 3)
    threaded = rp._dots(rows, i, rows, j)
    assert np.array_equal(serial, threaded)
    exact = np.einsum("ik,ik->i", rows[i].astype(np.float64), rows[j].astype(np.float64))
    np.testing.assert_allclose(threaded, exact, rtol=1e-13)


@pytest.mark.parametrize("k", [1, 3, 7, 8, 13, 200])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_compiled_inner_products_are_numpys_sums(k, dtype):
    # `_dot_rows` sums in the order of numpy's einsum on gathered float64 rows (what `_dots`
    # computed before it), so every fit is unchanged; any order would meet rtol=1e-13, and
    # equality holds where numpy's einsum sums two lanes of four products a step (SSE2 builds)
    from sssbake.pipeline.techniques.prt.reference_points import _dots

    rng = np.random.default_rng(k)
    a = rng.standard_normal((50, 3 * k)).astype(dtype)
    b = rng.standard_normal((40, 3 * k))
    for count in (0, 1, 3, 4, 5, 1001):
        i, j = rng.integers(0, 50, count), rng.integers(0, 40, count)
        numpy_sums = np.einsum("ick,ick->i", a[i].reshape(count, 3, k).astype(np.float64), b[j].reshape(count, 3, k))
        dots = _dots(a, i, b, j)
        np.testing.assert_allclose(dots, numpy_sums, rtol=1e-13, atol=1e-300)
        assert np.array_equal(dots, numpy_sums) or not _einsum_sums_in_two_lanes()


def _einsum_sums_in_two_lanes() -> bool:
    """Whether numpy's einsum sums a contiguous float64 row as two lanes of four products a
    step (the order `_dot_rows` follows): on a row whose sum depends on the order, it does."""
    x = np.array([1e16, 0.0, 1.0, 0.0, -1e16, 0.0, 1.0, 0.0])
    # two lanes: 1e16 + (1 + (-1e16 + 1)) = 0; in order: 1; four lanes: (1e16 - 1e16) + (1 + 1) = 2
    return float(np.einsum("i,i->", x, np.ones(8))) == 0.0


def test_run_minima_are_the_first_of_each_run_in_lexsort_order():
    # `_run_minima` replaces np.lexsort's per-run first (ties, NaN and -0.0 included)
    from sssbake.pipeline.techniques.prt.reference_points import _run_minima

    rng = np.random.default_rng(5)
    owner = np.sort(rng.integers(0, 300, 3000))
    primary = rng.integers(0, 4, 3000).astype(np.float64)
    secondary = rng.integers(0, 3, 3000).astype(np.float64)
    primary[rng.random(3000) < 0.1] = np.nan
    secondary[rng.random(3000) < 0.1] = np.nan
    primary[primary == 0.0] = np.where(rng.random(np.count_nonzero(primary == 0.0)) < 0.5, -0.0, 0.0)
    order = np.lexsort((secondary, primary, owner))
    expected = order[np.concatenate([[True], np.diff(owner[order]) != 0])]
    assert np.array_equal(_run_minima(owner, primary, secondary), expected)
    assert len(_run_minima(owner[:0], primary[:0], secondary[:0])) == 0


def closest_point_barycentrics_numpy(p: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`closest_point_barycentrics` in numpy (same arguments and results): the definition its
    compiled loop follows value for value."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e0, e1, rel = b - a, c - a, p - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((e0, e0), (e0, e1), (e1, e1)))
    d20, d21 = np.einsum("ij,ij->i", rel, e0), np.einsum("ij,ij->i", rel, e1)
    den = d00 * d11 - d01 * d01
    ok = den > 1e-12 * d00 * d11  # not degenerate (relative to the edge lengths)
    safe = np.where(ok, den, 1.0)
    v = (d11 * d20 - d01 * d21) / safe
    w = (d00 * d21 - d01 * d20) / safe
    plane = np.column_stack([1.0 - v - w, v, w])
    inside = ok & (plane.min(axis=1) >= -INSIDE_EPS)

    # Outside (or degenerate): the nearest point over the three edges.
    best_d = np.full(len(p), np.inf)
    best = np.zeros((len(p), 3))
    for i, j in ((0, 1), (1, 2), (2, 0)):
        edge = tri[:, j] - tri[:, i]
        length2 = np.einsum("ij,ij->i", edge, edge)
        t = np.clip(np.einsum("ij,ij->i", p - tri[:, i], edge) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
        d = np.linalg.norm(p - tri[:, i] - t[:, None] * edge, axis=1)
        closer = d < best_d
        best_d = np.where(closer, d, best_d)
        row = np.zeros((len(p), 3))
        row[:, i], row[:, j] = 1.0 - t, t
        best[closer] = row[closer]
    inner = np.clip(plane, 0.0, None)
    inner /= np.where(inner.sum(axis=1) > 0, inner.sum(axis=1), 1.0)[:, None]
    bary = np.where(inside[:, None], inner, best)
    normal = np.cross(e0, e1)
    normal_length = np.sqrt(np.where(ok, np.einsum("ij,ij->i", normal, normal), 1.0))
    plane_d = np.abs(np.einsum("ij,ij->i", rel, normal)) / normal_length
    return bary, np.where(inside, plane_d, best_d), inside


def test_compiled_closest_points_are_the_numpy_definition():
    rng = np.random.default_rng(9)
    n = 20000
    p, tri = rng.standard_normal((n, 3)), rng.standard_normal((n, 3, 3))
    tri[:500, 2] = tri[:500, 1]  # degenerate: an edge twice
    tri[500:1000, 1:] = tri[500:1000, :1]  # a point
    p[1000:4000] = np.einsum("mkj,k->mj", tri[1000:4000], [0.2, 0.3, 0.5])  # in the plane, inside
    p[4000:5000] = tri[4000:5000, 0]  # on a corner
    got, expected = closest_point_barycentrics(p, tri), closest_point_barycentrics_numpy(p, tri)
    for a, b in zip(got, expected):
        assert np.array_equal(a, b)
