"""Reference points for prt compression (Hao & Varshney 2004 §4.2): a subset of the surface
vertices from simplification, and for every vertex the simplified triangle it projects into with
its barycentric weights there. Least-squares weights (the paper's suggested improvement) refit
those weights to the signal itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .simplify import simplify

#: Triangles searched around a vertex that lies outside all triangles of its parent's ring.
NEAREST = 16


@dataclass(frozen=True, eq=False)
class ReferencePoints:
    """Attributes
    ----------
    ref_vertices : (R,) int64
        Surface vertex of each reference point.
    triangles : (F, 3) int64
        Simplified triangles over reference points.
    vertex_triangle : (n,) int64
        Each surface vertex's triangle.
    weights : (n, 3) float64
        Its barycentric weights on that triangle's corners (>= 0, sum 1; a reference point has
        weight 1 on itself).
    """

    ref_vertices: np.ndarray
    triangles: np.ndarray
    vertex_triangle: np.ndarray
    weights: np.ndarray


def reference_points(positions: np.ndarray, faces: np.ndarray, count: int) -> ReferencePoints:
    """Pick about `count` reference points by simplification and attach every vertex to a triangle.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    count : int
        Reference points wanted (the simplifier keeps about half as many vertices as faces).
    """
    positions = np.asarray(positions, dtype=np.float64)
    n = len(positions)
    if count < 3:
        raise ValueError(f"reference points: need at least 3, got {count}")
    simple = simplify(positions, faces, target_count=max(1, 2 * count))
    tri = simple.faces
    corners = simple.kept[tri]  # surface vertices of each simplified triangle's corners
    parent = simple.collapse_map.copy()

    # Candidates: the simplified triangles around the vertex's parent (the vertex it collapsed into).
    incident_face = np.repeat(np.arange(len(tri)), 3)
    incident_vertex = tri.ravel()
    order = np.argsort(incident_vertex, kind="stable")
    starts = np.searchsorted(incident_vertex[order], np.arange(len(simple.kept) + 1))
    count_of = np.diff(starts)
    has = (parent >= 0) & (count_of[np.maximum(parent, 0)] > 0)
    vertices = np.flatnonzero(has)
    per = count_of[parent[vertices]]
    pair_vertex = np.repeat(vertices, per)
    local = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)
    pair_face = incident_face[order[starts[parent[pair_vertex]] + local]]
    bary = _barycentric(positions[pair_vertex], positions[corners[pair_face]])
    score = bary.min(axis=1)
    # Best candidate per vertex: the one it lies most inside of.
    best = np.lexsort((-score, pair_vertex))
    first = np.concatenate([[True], pair_vertex[best][1:] != pair_vertex[best][:-1]])
    chosen = best[first]

    vertex_triangle = np.zeros(n, dtype=np.int64)
    weights = np.zeros((n, 3))
    vertex_triangle[pair_vertex[chosen]] = pair_face[chosen]
    weights[pair_vertex[chosen]] = bary[chosen]
    # Vertices outside every triangle around their parent (collapses can carry a vertex beyond
    # the parent's ring) or without a parent: the best of the nearest triangles.
    outside = np.full(n, True)
    outside[pair_vertex[chosen]] = score[chosen] < -1e-9
    lost = np.flatnonzero(outside)
    if len(lost):
        centroids = positions[corners].mean(axis=1)
        k = min(NEAREST, len(tri))
        _, nearest = cKDTree(centroids).query(positions[lost], k=k)
        nearest = nearest.reshape(len(lost), k)
        bary = _barycentric(np.repeat(positions[lost], k, axis=0), positions[corners[nearest.ravel()]])
        best = bary.min(axis=1).reshape(len(lost), k).argmax(axis=1)
        vertex_triangle[lost] = nearest[np.arange(len(lost)), best]
        weights[lost] = bary.reshape(len(lost), k, 3)[np.arange(len(lost)), best]
    # Outside every candidate (beyond a fold or the boundary): clamp onto the triangle.
    weights = np.clip(weights, 0.0, None)
    total = weights.sum(axis=1, keepdims=True)
    weights = np.where(total > 0, weights / np.where(total > 0, total, 1.0), 1.0 / 3.0)
    return ReferencePoints(simple.kept.astype(np.int64), tri.astype(np.int64), vertex_triangle, weights)


def least_squares_weights(q: np.ndarray, q_ref: np.ndarray, refs: ReferencePoints,
                          regularisation: float = 1e-3) -> np.ndarray:
    """Per vertex, weights summing to 1 that best reproduce its q from its triangle's references.

    Minimises Σ_c Σ_j (q - Σ_k w_k q_ref,k)² + λ ||w - w_bary||² (channels share the weights; λ is
    `regularisation` times the vertex's mean squared difference, so flat vertices keep their
    barycentric weights).

    Parameters
    ----------
    q : (3, n, K) float64
        The signal at every vertex.
    q_ref : (3, R, K) float64
        The signal at the reference points as the runtime will see it (after quantisation).
    refs : ReferencePoints

    Returns
    -------
    (n, 3) float64
        Weights summing to 1; they may leave [0, 1].
    """
    corners = refs.triangles[refs.vertex_triangle]  # (n, 3) reference indices
    n = q.shape[1]
    # w = (w0, w1, 1 - w0 - w1): residual = (q - r2) - w0 (r0 - r2) - w1 (r1 - r2)
    r2 = q_ref[:, corners[:, 2], :]
    target = (q - r2).transpose(1, 0, 2).reshape(n, -1)
    a0 = (q_ref[:, corners[:, 0], :] - r2).transpose(1, 0, 2).reshape(n, -1)
    a1 = (q_ref[:, corners[:, 1], :] - r2).transpose(1, 0, 2).reshape(n, -1)
    g = np.empty((n, 2, 2))
    g[:, 0, 0] = np.einsum("ij,ij->i", a0, a0)
    g[:, 0, 1] = g[:, 1, 0] = np.einsum("ij,ij->i", a0, a1)
    g[:, 1, 1] = np.einsum("ij,ij->i", a1, a1)
    b = np.column_stack([np.einsum("ij,ij->i", a0, target), np.einsum("ij,ij->i", a1, target)])
    lam = regularisation * (g[:, 0, 0] + g[:, 1, 1]) / 2.0 + 1e-300
    g[:, 0, 0] += lam
    g[:, 1, 1] += lam
    b += lam[:, None] * refs.weights[:, :2]
    w01 = np.linalg.solve(g, b[:, :, None])[:, :, 0]
    return np.column_stack([w01, 1.0 - w01.sum(axis=1)])


def _barycentric(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(m, 3) barycentrics of points p (m, 3) projected onto the planes of triangles tri (m, 3, 3);
    -inf rows for degenerate triangles."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    ok = den > 1e-12 * (d00 * d11 + 1e-300)
    safe = np.where(ok, den, 1.0)
    v = (d11 * d20 - d01 * d21) / safe
    w = (d00 * d21 - d01 * d20) / safe
    out = np.column_stack([1.0 - v - w, v, w])
    out[~ok] = -np.inf
    return out
