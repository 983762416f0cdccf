"""Reference points for prt compression (Hao & Varshney 2004 §4.2): a subset of the surface
vertices from simplification, and for every vertex the simplified triangle it lies on with its
barycentric weights there. Beyond the paper: least-squares weights refit those weights to the
signal itself, and refinement adds points where the signal is fitted worst.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

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
#: Signal values gathered at once for a weight fit's inner products (rows × 3 × K, 32 MB a copy).
FIT_ELEMENTS = 1 << 22
#: Threads `_dots` sums its chunks on.
THREADS = min(4, os.cpu_count() or 1)


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
    """Per vertex, the candidate triangle nearest to it.

    Returns (n,) triangle, (n, 3) closest-point barycentrics, (n,) distance (inf without
    candidates) and (n,) whether that closest point is inside the triangle (not on an edge).
    """
    bary, dist, inside = closest_point_barycentrics(positions[pair_vertex], corners[pair_face])
    # Nearest first; among equally near (a reference point on all its triangles), the most inside.
    order = np.lexsort((-bary.min(axis=1), dist, pair_vertex))
    first = order[np.concatenate([[True], np.diff(pair_vertex[order]) != 0])] if len(order) else order
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
    corner_of = tri[refs.vertex_triangle].ravel()  # (3n,)
    per = np.diff(starts)[corner_of]
    owner = np.repeat(np.repeat(np.arange(n), 3), per)
    local = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)
    candidate = incident[np.repeat(starts[corner_of], per) + local] // 3
    key = owner * len(tri) + candidate
    pairs = key[unique_keys(key, n * len(tri))[0]]  # sorted by vertex, duplicates gone
    owner, candidate = pairs // len(tri), pairs % len(tri)
    own = _is_reference(refs)
    keep = ~own[owner]
    owner, candidate = owner[keep], candidate[keep]
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
        order = np.lexsort((misfit, v))
        first = order[np.concatenate([[True], np.diff(v[order]) != 0])]
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
    """q as given when float32 (`_dots` reads it in float64 chunks; a float64 copy would double
    the stage's largest array), else as float64; q_ref as float64."""
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

    Rows pair `vertices` (m,) with `triangles[which]` (m,) of (T, 3) reference indices. The normal
    equations come from inner products, each computed once: ⟨q_v, r⟩ per distinct (vertex,
    reference) pair (a vertex's ~15 candidate triangles share ~10 references), ⟨r, r'⟩ per
    distinct triangle, |q_v|² per vertex: ~2.7× faster than forming the residuals row by row
    (benchmarks/README.md#prt-reference-points).

    Returns (m, 2) weights and (m,) misfit Σ_c Σ_j residual² (unregularised).
    """
    m, r = len(vertices), q_ref.shape[1]
    rows_q = _vertex_rows(q)
    rows_ref = np.ascontiguousarray(_vertex_rows(q_ref), dtype=np.float64)
    corners = triangles[which]
    key = (vertices[:, None].astype(np.int64) * r + corners).ravel()
    first, back = unique_keys(key, (int(vertices.max(initial=0)) + 1) * r)
    pair = key[first]
    qr = _dots(rows_q, pair // r, rows_ref, pair % r)[back].reshape(m, 3)  # ⟨q_v, r_k⟩
    first, tri_back = unique_keys(which, len(triangles))
    t = triangles[which[first]]
    r00, r01, r02, r11, r12, r22 = (_dots(rows_ref, t[:, k], rows_ref, t[:, l])[tri_back]
                                    for k, l in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    first, vert_back = unique_keys(vertices, int(vertices.max(initial=0)) + 1)
    vert = vertices[first]
    qq = _dots(rows_q, vert, rows_q, vert)[vert_back]
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


def _vertex_rows(q: np.ndarray) -> np.ndarray:
    """(n, 3, K) view of a (3, n, K) signal: a C-contiguous one when q is a view of vertex-major
    memory (`precompute_prt`'s q), whose rows `_dots` then gathers as single runs."""
    return np.moveaxis(q, 0, 1)


def _dots(a: np.ndarray, i: np.ndarray, b: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(len(i),) Σ_c Σ_k a[i, c, k] b[j, c, k] in float64, for (n, 3, K) rows (`_vertex_rows`) of
    float32 or float64, in chunks of rows (bounds the gathered copies).

    Float32 inputs are upcast per chunk: their products are exact in float64, so the sums are
    the float64 sums of the same values (the normal equations cancel heavily: `_fit`'s misfit).
    """
    out = np.empty(len(i))
    rows = max(1, FIT_ELEMENTS // (a.shape[1] * a.shape[2]))

    def chunk(s: int) -> None:
        x = a[i[s:s + rows]].astype(np.float64, copy=False)
        y = b[j[s:s + rows]].astype(np.float64, copy=False)
        out[s:s + rows] = np.einsum("ick,ick->i", x, y)

    # the gathers and sums release the GIL: 1.85x faster on 2 cores, every sum the same
    starts = range(0, len(i), rows)
    if len(starts) > 1 and THREADS > 1:
        with ThreadPoolExecutor(THREADS) as pool:
            list(pool.map(chunk, starts))
    else:
        for s in starts:
            chunk(s)
    return out
