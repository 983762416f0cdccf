"""Reference points for prt compression (Hao & Varshney 2004 §4.2): a subset of the surface
vertices from simplification, and for every vertex the simplified triangle it lies on with its
barycentric weights there. Beyond the paper: least-squares weights refit those weights to the
signal itself, and refinement adds points where the signal is fitted worst.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.core.integer_keys import unique_keys
from sssbake.pipeline.core.surface import area_weighted_normals
from sssbake.pipeline.mesh.simplify import Simplified, simplify

#: Barycentric tolerance for "the projection lies in the triangle" (relative, unitless).
INSIDE_EPS = 1e-6
#: Simplified triangles (nearest by centroid) searched for a vertex outside all of its parent's.
FALLBACK_CANDIDATES = 16
#: Rounds of `refine_reference_points` (gains stop after the 4th:
#: benchmarks/README.md#prt-reference-points).
REFINE_ROUNDS = 4
#: Defaults of the weight fits: ridge towards the prior weights relative to the normal matrix's
#: mean diagonal, and the clip of w_0, w_1 (see `least_squares_weights`).
REGULARISATION, LIMIT = 1e-3, 4.0
#: Threads `_dots` sums on, and the fewest pairs worth a thread of their own.
THREADS = min(4, os.cpu_count() or 1)
DOT_PAIRS = 4096


@dataclass(frozen=True, eq=False)
class ReferencePoints:
    """Attributes
    ----------
    ref_vertices : (R,) int64
        Surface vertex of each reference point (``Simplified.kept``).
    triangles : (F, 3) int64
        Simplified triangles over reference points (indices into ``ref_vertices``).
    vertex_triangle : (n,) int64
        Each surface vertex's triangle.
    weights : (n, 3) float64
        Barycentric weights of the vertex's closest point on that triangle (>= 0, sum 1; a
        reference point has weight 1 on itself).
    """

    ref_vertices: np.ndarray
    triangles: np.ndarray
    vertex_triangle: np.ndarray
    weights: np.ndarray


def reference_points(positions: np.ndarray, faces: np.ndarray, count: int) -> ReferencePoints:
    """Pick about `count` reference points by quadric simplification and attach every vertex.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    count : int
        Reference points wanted, at least 3 (the simplifier's face target is scaled by the
        mesh's own face/vertex ratio, so the count is met to within a few percent).

    Returns
    -------
    ReferencePoints
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if count < 3:
        raise ValueError(f"reference points: need at least 3, got {count}; raise the reference fraction")
    used = max(1, len(np.unique(faces)))
    target = max(1, int(round(count * len(faces) / used)))
    return attach_vertices(positions, faces, simplify(positions, faces, target_count=target, snap=True))


def attach_vertices(positions: np.ndarray, faces: np.ndarray, simple: Simplified) -> ReferencePoints:
    """Give every surface vertex a simplified triangle and barycentric weights on it.

    Candidates are the simplified triangles around the vertex's collapse parent; the vertex goes to
    the one nearest to it (its projection then lies inside, as the paper's orientation test asks).
    When its closest point on every candidate lies on an edge (a fold, a boundary, a parent whose
    triangles all collapsed away) the `FALLBACK_CANDIDATES` triangles with the nearest centroids
    facing the same way are searched too.

    Parameters
    ----------
    positions : (n, 3) float64
        Surface vertices.
    faces : (m, 3) int64
        Surface triangles (for vertex normals).
    simple : Simplified
        From ``simplify(positions, faces, ..., snap=True)``.

    Returns
    -------
    ReferencePoints
    """
    positions = np.asarray(positions, dtype=np.float64)
    n = len(positions)
    if len(simple.collapse_map) != n:
        raise ValueError(f"reference points: the simplification is of {len(simple.collapse_map)} vertices, "
                         f"the surface has {n}; simplify this surface")
    tri = np.asarray(simple.faces, dtype=np.int64)
    if len(tri) == 0:
        raise ValueError("reference points: the simplified mesh has no triangles; ask for more reference points")
    kept = np.asarray(simple.kept, dtype=np.int64)
    corners = positions[kept[tri]]  # (F, 3, 3): snapped, so the kept vertices' own positions

    # Candidate pairs (vertex, triangle) around each vertex's parent, as CSR over simplified vertices.
    parent = np.asarray(simple.collapse_map, dtype=np.int64)
    incident = np.argsort(tri.ravel(), kind="stable")
    starts = np.searchsorted(tri.ravel()[incident], np.arange(len(kept) + 1))
    per = np.where(parent >= 0, np.diff(starts)[np.maximum(parent, 0)], 0)
    pair_vertex = np.repeat(np.arange(n), per)
    local = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)
    pair_face = incident[starts[parent[pair_vertex]] + local] // 3
    vertex_triangle, weights, distance, inside = _nearest(positions, corners, pair_vertex, pair_face, n)

    lost = np.flatnonzero(~inside)
    if len(lost):
        normals = area_weighted_normals(positions, np.asarray(faces, dtype=np.int64))
        face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        k = min(FALLBACK_CANDIDATES, len(tri))
        _, near = cKDTree(corners.mean(axis=1)).query(positions[lost], k=k)
        near = near.reshape(len(lost), k)
        # Facing the same way keeps a vertex off the far side of a thin part.
        facing = np.einsum("mkj,mj->mk", face_normals[near], normals[lost]) > 0.0
        vertex = np.repeat(lost, k).reshape(len(lost), k)[facing]
        t2, w2, d2, _ = _nearest(positions, corners, vertex, near[facing], n)
        better = np.flatnonzero(d2 < distance)
        vertex_triangle[better], weights[better], distance[better] = t2[better], w2[better], d2[better]

    unplaced = np.flatnonzero(~np.isfinite(distance))
    if len(unplaced):  # no candidate at all (an isolated vertex): the nearest centroid, any side
        _, near = cKDTree(corners.mean(axis=1)).query(positions[unplaced])
        t2, w2, _, _ = _nearest(positions, corners, unplaced, near, n)
        vertex_triangle[unplaced], weights[unplaced] = t2[unplaced], w2[unplaced]

    # A reference point sits exactly on a corner of its triangles; make it exactly weight 1.
    is_ref = kept[tri[vertex_triangle]] == np.arange(n)[:, None]
    own = is_ref.any(axis=1)
    weights[own] = is_ref[own].astype(np.float64)
    return ReferencePoints(kept, tri, vertex_triangle, weights)


def _nearest(positions: np.ndarray, corners: np.ndarray, pair_vertex: np.ndarray, pair_face: np.ndarray,
             n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per vertex, the candidate triangle nearest to it (`pair_vertex` sorted).

    Returns (n,) triangle, (n, 3) closest-point barycentrics, (n,) distance (inf without
    candidates) and (n,) whether that closest point is inside the triangle (not on an edge).
    """
    bary, dist, inside = closest_point_barycentrics(positions[pair_vertex], corners[pair_face])
    # Nearest first; among equally near (a reference point on all its triangles), the most inside.
    first = _run_minima(pair_vertex, dist, -bary.min(axis=1))
    vertex_triangle = np.zeros(n, dtype=np.int64)
    weights = np.full((n, 3), 1.0 / 3.0)
    distance = np.full(n, np.inf)
    is_inside = np.zeros(n, dtype=bool)
    v = pair_vertex[first]
    vertex_triangle[v], weights[v] = pair_face[first], bary[first]
    distance[v], is_inside[v] = dist[first], inside[first]
    return vertex_triangle, weights, distance, is_inside


def closest_point_barycentrics(p: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of triangles to points.

    Parameters
    ----------
    p : (m, 3) float64
    tri : (m, 3, 3) float64
        Triangle corners (degenerate triangles allowed: their closest point is on an edge).

    Returns
    -------
    bary : (m, 3) float64
        Barycentrics of the closest point (>= 0, sum 1).
    distance : (m,) float64
    inside : (m,) bool
        The projection onto the triangle's plane lies inside (barycentrics >= -`INSIDE_EPS`).
    """
    p = np.ascontiguousarray(p, dtype=np.float64)
    tri = np.ascontiguousarray(tri, dtype=np.float64)
    bary, distance, inside = np.empty((len(p), 3)), np.empty(len(p)), np.empty(len(p), dtype=bool)
    _closest_points(p, tri, bary, distance, inside)
    return bary, distance, inside


@numba.njit(cache=True, nogil=True)
def _closest_points(p, tri, bary, distance, inside):
    """`closest_point_barycentrics` point by point, its numpy form's values exactly (that form is
    tests/techniques/prt/test_reference_points.py's oracle; ~10x slower): the projection onto the
    plane when it lies inside (not degenerate: den > 1e-12 d00 d11), else the nearest point over
    the three edges (the first of equally near ones)."""
    for m in range(len(p)):
        ax, ay, az = tri[m, 0, 0], tri[m, 0, 1], tri[m, 0, 2]
        e0x, e0y, e0z = tri[m, 1, 0] - ax, tri[m, 1, 1] - ay, tri[m, 1, 2] - az
        e1x, e1y, e1z = tri[m, 2, 0] - ax, tri[m, 2, 1] - ay, tri[m, 2, 2] - az
        rx, ry, rz = p[m, 0] - ax, p[m, 1] - ay, p[m, 2] - az
        d00 = _dot3(e0x, e0y, e0z, e0x, e0y, e0z)
        d01 = _dot3(e0x, e0y, e0z, e1x, e1y, e1z)
        d11 = _dot3(e1x, e1y, e1z, e1x, e1y, e1z)
        d20 = _dot3(rx, ry, rz, e0x, e0y, e0z)
        d21 = _dot3(rx, ry, rz, e1x, e1y, e1z)
        den = d00 * d11 - d01 * d01
        ok = den > 1e-12 * d00 * d11
        safe = den if ok else 1.0
        v = (d11 * d20 - d01 * d21) / safe
        w = (d00 * d21 - d01 * d20) / safe
        u = 1.0 - v - w
        inside[m] = ok and min(u, min(v, w)) >= -INSIDE_EPS
        if inside[m]:
            u, v, w = max(u, 0.0), max(v, 0.0), max(w, 0.0)
            total = _sum3(u, v, w)
            total = total if total > 0 else 1.0
            bary[m, 0], bary[m, 1], bary[m, 2] = u / total, v / total, w / total
            nx, ny, nz = e0y * e1z - e0z * e1y, e0z * e1x - e0x * e1z, e0x * e1y - e0y * e1x
            distance[m] = abs(_dot3(rx, ry, rz, nx, ny, nz)) / np.sqrt(_dot3(nx, ny, nz, nx, ny, nz))
            continue
        distance[m] = np.inf
        bary[m] = 0.0
        for i in range(3):
            j = (i + 1) % 3
            ex, ey, ez = tri[m, j, 0] - tri[m, i, 0], tri[m, j, 1] - tri[m, i, 1], tri[m, j, 2] - tri[m, i, 2]
            sx, sy, sz = p[m, 0] - tri[m, i, 0], p[m, 1] - tri[m, i, 1], p[m, 2] - tri[m, i, 2]
            length2 = _dot3(ex, ey, ez, ex, ey, ez)
            t = min(max(_dot3(sx, sy, sz, ex, ey, ez) / (length2 if length2 > 0 else 1.0), 0.0), 1.0)
            dx, dy, dz = sx - t * ex, sy - t * ey, sz - t * ez
            d = np.sqrt(_sum3(dx * dx, dy * dy, dz * dz))
            if d < distance[m]:
                distance[m] = d
                bary[m, i], bary[m, j], bary[m, 3 - i - j] = 1.0 - t, t, 0.0


@numba.njit(cache=True, nogil=True, inline="always")
def _dot3(x0, x1, x2, y0, y1, y2):
    """A 3-vector dot product as numpy's einsum sums it (lanes of even and odd elements)."""
    return (x0 * y0 + x2 * y2) + x1 * y1


@numba.njit(cache=True, nogil=True, inline="always")
def _sum3(x0, x1, x2):
    """Three values as numpy's sum along a row sums them (in order)."""
    return (x0 + x1) + x2


def least_squares_weights(q: np.ndarray, q_ref: np.ndarray, refs: ReferencePoints,
                          regularisation: float = REGULARISATION, limit: float = LIMIT) -> np.ndarray:
    """Per vertex, weights summing to 1 that best reproduce its q from its triangle's references.

    Minimises Σ_c Σ_j (q - Σ_k w_k q_ref,k)² + λ ||w - w_bary||² over (w_0, w_1), w_2 = 1 - w_0 - w_1
    (channels share the weights; λ is `regularisation` times the mean diagonal of the vertex's
    2×2 normal matrix, so a vertex whose references carry the same signal keeps its barycentric
    weights). w_0 and w_1 are then clipped to [-limit, limit] (one extreme vertex would otherwise
    widen ``weight_scale`` and coarsen every vertex's 16-bit weights); a vertex whose clipped fit
    is worse than its barycentric weights keeps those. Reference points keep weight 1 on themselves.

    Parameters
    ----------
    q : (3, n, K) float64
        The signal at every vertex.
    q_ref : (3, R, K) float64
        The signal at the reference points as the runtime will see it (after quantisation).
    refs : ReferencePoints
    regularisation, limit : float

    Returns
    -------
    (n, 3) float64
        Weights summing to 1: w_0, w_1 in [-limit, limit], w_2 in [1 - 2 limit, 1 + 2 limit]
        (the limit binds for a fraction of a percent of the vertices:
        benchmarks/README.md#prt-reference-points).
    """
    q, q_ref = _check_signals(q, q_ref, refs)
    n = len(refs.vertex_triangle)
    vertices = np.arange(n)
    w01, _ = _fit(q, q_ref, vertices, refs.triangles, refs.vertex_triangle, refs.weights[:, :2],
                  regularisation, limit)
    out = np.column_stack([w01, 1.0 - w01.sum(axis=1)])
    own = _is_reference(refs)
    out[own] = refs.weights[own]
    return out


def best_fit_triangles(q: np.ndarray, q_ref: np.ndarray, refs: ReferencePoints,
                       regularisation: float = REGULARISATION, limit: float = LIMIT) -> ReferencePoints:
    """Move each vertex to the simplified triangle whose least-squares weights reproduce its q best.

    Candidates are the triangles sharing a corner with the vertex's geometric triangle (about 15);
    each gets `least_squares_weights`-style weights (regularised towards the barycentrics on the
    geometric triangle, towards its centroid elsewhere) and the smallest misfit wins. The runtime
    reads the same vertex_triangle/weights, so this costs no byte, and the error falls well below
    that of least-squares weights on the geometric triangle; a wider search gains little
    (benchmarks/README.md#prt-reference-points). Reference points stay on themselves.

    Parameters
    ----------
    q : (3, n, K) float64
    q_ref : (3, R, K) float64
        Reference signals as the runtime sees them.
    refs : ReferencePoints
        The geometric assignment (`reference_points`).
    regularisation, limit : float
        As in `least_squares_weights`.

    Returns
    -------
    ReferencePoints
        Same reference points and triangles; new vertex_triangle and (least-squares) weights.
    """
    q, q_ref = _check_signals(q, q_ref, refs)
    tri = refs.triangles
    n = len(refs.vertex_triangle)
    incident = np.argsort(tri.ravel(), kind="stable")
    starts = np.searchsorted(tri.ravel()[incident], np.arange(len(refs.ref_vertices) + 1))
    # (vertex, candidate) pairs: the triangles around each corner of the geometric triangle.
    corners = tri[refs.vertex_triangle]
    own = _is_reference(refs)
    owner, candidate = _candidate_pairs(corners, starts, incident // 3, own,
                                        int(np.diff(starts)[corners].sum()))
    geometric = candidate == refs.vertex_triangle[owner]
    prior = np.where(geometric[:, None], refs.weights[owner, :2], 1.0 / 3.0)

    best = np.full(n, np.inf)
    vertex_triangle = refs.vertex_triangle.copy()
    weights = refs.weights.copy()
    chunk = 1 << 20  # (vertex, candidate) rows per fit: bounds its per-row arrays (the gathers bound themselves)
    for s in range(0, len(owner), chunk):
        v, t = owner[s:s + chunk], candidate[s:s + chunk]
        w01, misfit = _fit(q, q_ref, v, tri, t, prior[s:s + chunk], regularisation, limit)
        # Per vertex, the chunk's best pair (pairs are sorted by vertex, so minima are per run).
        first = _run_minima(v, misfit, np.zeros(len(v)))
        win = first[misfit[first] < best[v[first]]]
        best[v[win]] = misfit[win]
        vertex_triangle[v[win]] = t[win]
        weights[v[win]] = np.column_stack([w01[win], 1.0 - w01[win].sum(axis=1)])
    return ReferencePoints(refs.ref_vertices, tri, vertex_triangle, weights)


def refine_reference_points(positions: np.ndarray, refs: ReferencePoints, q: np.ndarray, count: int,
                            rounds: int = REFINE_ROUNDS) -> ReferencePoints:
    """Add reference points where the fit is worst, up to `count` (at most one per triangle and
    round, so a count far above the start's may not be reached).

    In each of `rounds` rounds: fit every vertex on its triangle (`least_squares_weights`, the
    references' tables being their own q), sum the misfits of the vertices over the simplified
    triangle they lie on, and in each of the worst triangles make its worst vertex a reference
    point, splitting the triangle 1-to-3 at it; the vertices of a split triangle move to the
    nearest of its three parts. The runtime reads the result like any other triangulation. At the
    same bytes this beats placing every point by simplification; ranking by the best-fit misfit
    (`best_fit_triangles`) instead gains little at three times the compression time
    (benchmarks/README.md#prt-reference-points).

    Parameters
    ----------
    positions : (n, 3) float64
        Surface vertices.
    refs : ReferencePoints
        The starting points (`reference_points`).
    q : (3, n, K) float64
        The signal.
    count : int
        Reference points wanted (at most the vertices).
    rounds : int

    Returns
    -------
    ReferencePoints
        The starting points plus the new ones (appended), the split triangulation, geometric
        attachment (as `attach_vertices` gives, for `best_fit_triangles` to refit).
    """
    positions = np.asarray(positions, dtype=np.float64)
    n = len(positions)
    for done in range(rounds):
        need = min(count, n) - len(refs.ref_vertices)
        if need <= 0:
            break
        misfit = _fit(q, q[:, refs.ref_vertices], np.arange(n), refs.triangles, refs.vertex_triangle,
                      refs.weights[:, :2], REGULARISATION, LIMIT)[1]
        misfit[_is_reference(refs)] = 0.0  # a reference point reproduces itself
        refs = _split_worst(positions, refs, misfit, -(-need // (rounds - done)))
    return refs


def _split_worst(positions: np.ndarray, refs: ReferencePoints, misfit: np.ndarray, m: int) -> ReferencePoints:
    """Make the worst vertex of each of the `m` triangles with the most misfit a reference point."""
    n = len(positions)
    home = refs.vertex_triangle
    is_ref = np.zeros(n, dtype=bool)
    is_ref[refs.ref_vertices] = True
    # Per triangle, its worst non-reference vertex.
    order = np.lexsort((-misfit, home))
    order = order[~is_ref[order]]
    worst = order[np.concatenate([[True], np.diff(home[order]) != 0])] if len(order) else order
    total = np.bincount(home, misfit, minlength=len(refs.triangles))
    chosen = worst[np.argsort(-total[home[worst]], kind="stable")[:m]]
    split = home[chosen]
    r, f, k = len(refs.ref_vertices), len(refs.triangles), len(chosen)
    new = r + np.arange(k)
    a, b, c = refs.triangles[split].T
    triangles = np.concatenate([refs.triangles, np.column_stack([b, c, new]), np.column_stack([c, a, new])])
    triangles[split] = np.column_stack([a, b, new])
    ref_vertices = np.concatenate([refs.ref_vertices, chosen])

    # The vertices of a split triangle go to the nearest of its three parts.
    part = np.full(f, -1)
    part[split] = np.arange(k)
    moved = np.flatnonzero(part[home] >= 0)
    j = part[home[moved]]
    candidates = np.column_stack([split[j], f + j, f + k + j])  # (moved, 3)
    corners = positions[ref_vertices[triangles[candidates]]]  # (moved, 3 parts, 3 corners, 3)
    bary, distance, _ = closest_point_barycentrics(np.repeat(positions[moved], 3, axis=0), corners.reshape(-1, 3, 3))
    pick = distance.reshape(-1, 3).argmin(axis=1)
    # A reference point stays on a part it is a corner of (others may be as near within rounding).
    corner = (ref_vertices[triangles[candidates]] == moved[:, None, None]).any(axis=2)
    pick = np.where(corner.any(axis=1), corner.argmax(axis=1), pick)
    vertex_triangle = home.copy()
    weights = refs.weights.copy()
    vertex_triangle[moved] = candidates[np.arange(len(moved)), pick]
    weights[moved] = bary.reshape(-1, 3, 3)[np.arange(len(moved)), pick]
    own = ref_vertices[triangles[vertex_triangle]] == np.arange(n)[:, None]
    mine = own.any(axis=1)
    weights[mine] = own[mine].astype(np.float64)
    return ReferencePoints(ref_vertices, triangles, vertex_triangle, weights)


def _check_signals(q: np.ndarray, q_ref: np.ndarray, refs: ReferencePoints) -> tuple[np.ndarray, np.ndarray]:
    """q as given when float32 (`_dots` reads it as float64; a float64 copy would double the
    stage's largest array), else as float64; q_ref as float64."""
    q, q_ref = _signal(q), np.asarray(q_ref, dtype=np.float64)
    n, r = len(refs.vertex_triangle), len(refs.ref_vertices)
    if q.ndim != 3 or q.shape[:2] != (3, n) or q_ref.shape != (3, r, q.shape[2]):
        raise ValueError(f"reference points: q must be (3, {n}, K) and q_ref (3, {r}, K), "
                         f"got {q.shape} and {q_ref.shape}")
    return q, q_ref


def _signal(q: np.ndarray) -> np.ndarray:
    """q unchanged when float32 or float64, else as float64."""
    q = np.asarray(q)
    return q if q.dtype in (np.float32, np.float64) else q.astype(np.float64)


def _is_reference(refs: ReferencePoints) -> np.ndarray:
    """(n,) whether each vertex is a corner of its own triangle (a reference point)."""
    corners = refs.ref_vertices[refs.triangles[refs.vertex_triangle]]
    return (corners == np.arange(len(corners))[:, None]).any(axis=1)


def _fit(q: np.ndarray, q_ref: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, which: np.ndarray,
         prior: np.ndarray, regularisation: float, limit: float) -> tuple[np.ndarray, np.ndarray]:
    """Regularised least-squares (w_0, w_1) of each vertex on the three reference points of a triangle.

    Rows pair `vertices` (m,), sorted, with `triangles[which]` (m,) of (T, 3) reference indices. The normal
    equations come from inner products, each computed once: ⟨q_v, r⟩ per distinct (vertex,
    reference) pair (a vertex's ~15 candidate triangles share ~10 references), ⟨r, r'⟩ per
    distinct triangle, |q_v|² per vertex: ~2.7× faster than forming the residuals row by row
    (benchmarks/README.md#prt-reference-points).

    Returns (m, 2) weights and (m,) misfit Σ_c Σ_j residual² (unregularised).
    """
    m = len(vertices)
    rows_q = _vertex_rows(q)
    rows_ref = _vertex_rows(q_ref)
    if rows_ref.dtype == np.float64 and np.array_equal(rows_ref.astype(np.float32), rows_ref):
        rows_ref = rows_ref.astype(np.float32)  # the same values (RGB tables' levels) in half the bytes
    vertices = np.asarray(vertices, dtype=np.int64)
    if np.any(vertices[1:] < vertices[:-1]):
        raise ValueError("reference points: the fit's rows must be sorted by vertex")
    corners = np.ascontiguousarray(triangles[which], dtype=np.int64)
    pair_vertex, pair_ref, back = _vertex_references(vertices, corners)
    qr = _dots(rows_q, pair_vertex, rows_ref, pair_ref)[back].reshape(m, 3)  # ⟨q_v, r_k⟩
    first, tri_back = unique_keys(which, len(triangles))
    t = triangles[which[first]]
    r00, r01, r02, r11, r12, r22 = (_dots(rows_ref, t[:, k], rows_ref, t[:, l])[tri_back]
                                    for k, l in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    run = np.concatenate([[True], vertices[1:] != vertices[:-1]])
    vert = vertices[run]
    qq = np.repeat(_dots(rows_q, vert, rows_q, vert), np.diff(np.append(np.flatnonzero(run), m)))
    # With a_k = r_k - r_2 and target q - r_2: g = ⟨a_k, a_l⟩, b = ⟨a_k, target⟩, rest = |target|².
    g = np.empty((m, 2, 2))
    g[:, 0, 0] = r00 - 2.0 * r02 + r22
    g[:, 0, 1] = g[:, 1, 0] = r01 - r02 - r12 + r22
    g[:, 1, 1] = r11 - 2.0 * r12 + r22
    b = np.column_stack([qr[:, 0] - r02 - qr[:, 2] + r22, qr[:, 1] - r12 - qr[:, 2] + r22])
    rest = qq - 2.0 * qr[:, 2] + r22
    lam = regularisation * 0.5 * np.abs(g[:, 0, 0] + g[:, 1, 1]) + np.finfo(np.float64).tiny
    w01 = np.linalg.solve(g + lam[:, None, None] * np.eye(2), (b + lam[:, None] * prior)[:, :, None])[:, :, 0]
    w01 = np.clip(w01, -limit, limit)

    def misfit(w):  # Σ_c Σ_j residual², from the normal equations
        return np.clip(rest - 2.0 * np.einsum("ni,ni->n", b, w) + np.einsum("ni,nij,nj->n", w, g, w), 0.0, None)

    fitted, fallback = misfit(w01), misfit(prior)
    better = fitted <= fallback
    return np.where(better[:, None], w01, prior), np.where(better, fitted, fallback)


@numba.njit(cache=True, nogil=True)
def _candidate_pairs(corners, starts, around, skip, bound):
    """(vertex, triangle) pairs sorted by vertex, then triangle, without repeats: for each vertex
    not in `skip`, the triangles around its triangle's `corners` (n, 3) (``around[starts[c]:
    starts[c + 1]]`` around corner c); `bound` is the sum of those counts. The triangles of a
    vertex are sorted among themselves (~15), not all keys at once (~6x faster)."""
    owner = np.empty(bound, dtype=np.int64)
    candidate = np.empty(bound, dtype=np.int64)
    order_buffer = np.empty(bound, dtype=np.int64)
    count = 0
    for v in range(len(corners)):
        if skip[v]:
            continue
        first = count
        for c in corners[v]:
            for e in range(starts[c], starts[c + 1]):
                candidate[count] = around[e]
                count += 1
        order = _sorted_indices(candidate, first, count, order_buffer)
        end, count = count, first
        for e in range(end - first):
            value = candidate[order[e]]
            if e == 0 or value != owner[count - 1]:
                owner[count] = value  # the triangles first, their vertex below
                count += 1
        candidate[first:count] = owner[first:count]
        owner[first:count] = v
    return owner[:count], candidate[:count]


@numba.njit(cache=True, nogil=True)
def _vertex_references(vertices, corners):
    """The distinct (vertex, reference) pairs of `_fit`'s rows, sorted, and each row corner's
    place among them ((m · 3,)): ``unique_keys`` of the keys vertex · R + corner, found per run
    of rows of one vertex (`vertices` sorted) among its ~45 corners, not among all keys at once."""
    m = len(vertices)
    keys = corners.ravel()
    pair_vertex = np.empty(3 * m, dtype=np.int64)
    pair_ref = np.empty(3 * m, dtype=np.int64)
    back = np.empty(3 * m, dtype=np.int64)
    order_buffer = np.empty(3 * m, dtype=np.int64)
    count = 0
    start = 0
    while start < m:
        end = start + 1
        while end < m and vertices[end] == vertices[start]:
            end += 1
        order = _sorted_indices(keys, 3 * start, 3 * end, order_buffer)
        for e in range(len(order)):
            if e == 0 or keys[order[e]] != keys[order[e - 1]]:
                pair_vertex[count] = vertices[start]
                pair_ref[count] = keys[order[e]]
                count += 1
            back[order[e]] = count - 1
        start = end
    return pair_vertex[:count], pair_ref[:count], back


@numba.njit(cache=True, nogil=True, inline="always")
def _sorted_indices(values, lo, hi, buffer):
    """The indices lo..hi - 1 ordered by `values` (insertion sort into `buffer[lo:hi]`: the
    runs are short, ~15 to 45, and a sort call per run would allocate)."""
    order = buffer[lo:hi]
    for e in range(hi - lo):
        k = e
        while k > 0 and values[order[k - 1]] > values[lo + e]:
            order[k] = order[k - 1]
            k -= 1
        order[k] = lo + e
    return order


@numba.njit(cache=True, nogil=True)
def _run_minima(owner, primary, secondary):
    """Per run of equal `owner` (sorted), the first index whose (primary, secondary) is least, NaN
    above every number: the first of each run in ``np.lexsort((secondary, primary, owner))``,
    without sorting (~20x faster)."""
    out = np.empty(len(owner), dtype=np.int64)
    count = 0
    for p in range(len(owner)):
        if p == 0 or owner[p] != owner[p - 1]:
            out[count] = p
            count += 1
            continue
        b = out[count - 1]
        if _less(primary[p], primary[b]) or (not _less(primary[b], primary[p]) and _less(secondary[p], secondary[b])):
            out[count - 1] = p
    return out[:count]


@numba.njit(cache=True, nogil=True, inline="always")
def _less(x, y):
    """x before y in numpy's sort order (NaN last)."""
    return x < y or (y != y and x == x)


def _vertex_rows(q: np.ndarray) -> np.ndarray:
    """(n, 3·K) rows of a (3, n, K) signal, in its own dtype: a view when q is a view of
    vertex-major memory (`precompute_prt`'s q), else a copy (of a float64 (3, n, K) array, as
    tests give)."""
    return np.moveaxis(q, 0, 1).reshape(q.shape[1], -1)


def _dots(a: np.ndarray, i: np.ndarray, b: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(len(i),) Σ_e a[i, e] b[j, e] in float64, for (n, 3·K) rows (`_vertex_rows`) of float32 or
    float64, summed by `_dot_rows` on `THREADS` threads (each writes its own slice).

    Float32 inputs are read as float64: their products are exact in float64, so the sums are
    the float64 sums of the same values (the normal equations cancel heavily: `_fit`'s misfit).
    """
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    i, j = np.asarray(i, dtype=np.int64), np.asarray(j, dtype=np.int64)
    out = np.empty(len(i))
    step = max(DOT_PAIRS, -(-len(i) // THREADS))
    starts = range(0, len(i), step)
    if len(starts) > 1:
        with ThreadPoolExecutor(THREADS) as pool:
            list(pool.map(lambda s: _dot_rows(a, i[s:s + step], b, j[s:s + step], out[s:s + step]), starts))
    else:
        _dot_rows(a, i, b, j, out)
    return out


@numba.njit(cache=True, nogil=True)
def _dot_rows(a, i, b, j, out):
    """out[p] = Σ_e a[i[p], e] b[j[p], e] in float64, summed in the order of numpy's einsum on
    contiguous float64 rows (`np.einsum("ick,ick->i", ...)`, which `_dots` gathered and summed
    before: the same sums, bit for bit, tests/techniques/prt/test_reference_points.py), without
    its gathered float64 copies of every row: two lanes (even and odd e), each adding four
    products per step of eight (`_lane_step`), then the tail two at a time, then lane 0 + lane 1.
    Four pairs at a time: one pair's two chains of dependent adds leave the adder idle."""
    m = a.shape[1]
    whole = m - m % 8
    p = 0
    while p + 4 <= len(i):
        x0, x1, x2, x3 = a[i[p]], a[i[p + 1]], a[i[p + 2]], a[i[p + 3]]
        y0, y1, y2, y3 = b[j[p]], b[j[p + 1]], b[j[p + 2]], b[j[p + 3]]
        e0 = e1 = e2 = e3 = o0 = o1 = o2 = o3 = 0.0
        for e in range(0, whole, 8):
            e0 = _lane_step(x0, y0, e, e0)
            o0 = _lane_step(x0, y0, e + 1, o0)
            e1 = _lane_step(x1, y1, e, e1)
            o1 = _lane_step(x1, y1, e + 1, o1)
            e2 = _lane_step(x2, y2, e, e2)
            o2 = _lane_step(x2, y2, e + 1, o2)
            e3 = _lane_step(x3, y3, e, e3)
            o3 = _lane_step(x3, y3, e + 1, o3)
        out[p] = _lane_tail(x0, y0, whole, e0, o0)
        out[p + 1] = _lane_tail(x1, y1, whole, e1, o1)
        out[p + 2] = _lane_tail(x2, y2, whole, e2, o2)
        out[p + 3] = _lane_tail(x3, y3, whole, e3, o3)
        p += 4
    for p in range(p, len(i)):
        x, y = a[i[p]], b[j[p]]
        even = odd = 0.0
        for e in range(0, whole, 8):
            even = _lane_step(x, y, e, even)
            odd = _lane_step(x, y, e + 1, odd)
        out[p] = _lane_tail(x, y, whole, even, odd)


@numba.njit(cache=True, nogil=True, inline="always")
def _lane_step(x, y, e, acc):
    """One lane's step of `_dot_rows`: elements e, e + 2, e + 4, e + 6 added last first."""
    return np.float64(x[e]) * y[e] + (np.float64(x[e + 2]) * y[e + 2] + (
        np.float64(x[e + 4]) * y[e + 4] + (np.float64(x[e + 6]) * y[e + 6] + acc)))


@numba.njit(cache=True, nogil=True, inline="always")
def _lane_tail(x, y, whole, even, odd):
    """The elements from `whole` on, two at a time into the lanes, then their sum."""
    for e in range(whole, len(x), 2):
        even = np.float64(x[e]) * y[e] + even
        if e + 1 < len(x):
            odd = np.float64(x[e + 1]) * y[e + 1] + odd
    return even + odd
