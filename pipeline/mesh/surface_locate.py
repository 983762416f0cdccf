"""Where points of one surface lie on a simplified copy of it: the nearest triangle and the
barycentric weights there (closest point on the triangles around the nearest few vertices)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point, points_to_barycentric

#: Nearest simplified vertices whose triangles are searched per point.
NEAREST = 4
#: Points located at once (bounds the candidate arrays: ~17 candidates a point, ~5 KB a point in all).
CHUNK = 16_384
#: Chunks located at once (numpy and the k-d tree release the GIL).
THREADS = 2


def locate_on_mesh(points: np.ndarray, positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closest triangle of (positions, faces) to each point, among those around its `NEAREST`
    nearest vertices.

    Parameters
    ----------
    points : (m, 3) float64
    positions : (k, 3) float64
    faces : (f, 3) int64

    Returns
    -------
    face : (m,) int64
    barycentric : (m, 3) float64
        Of the closest point, non-negative, summing to 1.
    """
    points = np.asarray(points, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    order = np.argsort(faces.reshape(-1), kind="stable")
    owner = order // 3
    counts = np.bincount(faces.reshape(-1), minlength=len(positions))
    start = np.r_[0, np.cumsum(counts)]
    width = int(counts.max()) if len(counts) else 0
    around = np.full((len(positions), width), -1, dtype=np.int64)  # faces around each vertex, padded
    slot = np.arange(len(order)) - np.repeat(start[:-1], counts)
    around[np.repeat(np.arange(len(positions)), counts), slot] = owner
    corners = positions[faces]
    # Each triangle's bounding sphere: a triangle whose sphere lies farther from a point than the
    # nearest corner of its candidates (at least as near as the closest triangle) cannot be the
    # closest; about a third of the candidates are dropped before the distance test.
    centre = corners.mean(axis=1)
    bound = np.sqrt(np.einsum("fkd,fkd->fk", corners - centre[:, None], corners - centre[:, None]).max(axis=1))
    tree = cKDTree(positions)
    face = np.empty(len(points), dtype=np.int64)
    bary = np.empty((len(points), 3))

    def chunk(s: int) -> None:
        p = points[s: s + CHUNK]
        nearest, near = tree.query(p, k=min(NEAREST, len(positions)))
        nearest, near = nearest.reshape(len(p), -1), near.reshape(len(p), -1)
        candidates = np.sort(around[near].reshape(len(p), -1), axis=1)
        candidates[:, 1:][candidates[:, 1:] == candidates[:, :-1]] = -1  # the vertices share faces
        row, col = np.nonzero(candidates >= 0)
        tri = candidates[row, col]
        reach = np.where(counts[near] > 0, nearest, np.inf).min(axis=1)  # the nearest corner of any candidate
        gap = np.sqrt(_squared_norm(p[row] - centre[tri])) - bound[tri]
        live = gap <= reach[row] + 1e-9 * bound[tri]  # margin: the rounding of both
        row, col, tri = row[live], col[live], tri[live]
        distance = np.full(candidates.shape, np.inf)
        distance[row, col] = estimate = _triangle_distance2(p[row], corners[tri])
        # Near-ties (a point nearest a shared edge or corner) are decided by trimesh's closest
        # points, first in candidate order, as when every candidate was tested with them (the
        # located points of the 150k dragon came out bit for bit the same; ties within rounding
        # can go either way). The margin is far above both computations' rounding (~1e-16 of
        # the triangle's size²).
        tie = estimate <= distance.min(axis=1)[row] * (1.0 + 1e-9) + 1e-12 * np.square(bound[tri])
        row, col, tri = row[tie], col[tie], tri[tie]
        closest = closest_point(corners[tri], p[row])
        exact = np.full(candidates.shape, np.inf)
        exact[row, col] = _squared_norm(closest - p[row])
        chosen = np.flatnonzero(col == np.argmin(exact, axis=1)[row])  # one per point
        best = tri[chosen]
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.clip(points_to_barycentric(corners[best], closest[chosen]), 0.0, None)
        # a triangle without area (the simplified copy can hold some) has no barycentric
        # weights: the point takes its nearest corner's value
        flat = np.flatnonzero(~np.isfinite(w).all(axis=1))
        if len(flat):
            offsets = corners[best[flat]] - closest[chosen[flat], None]
            w[flat] = np.eye(3)[np.argmin(np.einsum("ikd,ikd->ik", offsets, offsets), axis=1)]
        face[s: s + len(p)] = best
        bary[s: s + len(p)] = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)

    with ThreadPoolExecutor(THREADS) as pool:
        list(pool.map(chunk, range(0, len(points), CHUNK)))
    return face, bary


def _squared_norm(v: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", v, v)


def _triangle_distance2(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(m,) squared distance from points p (m, 3) to triangles tri (m, 3 corners, 3).

    The distance to the plane where the point projects inside the triangle, else to the nearest
    of its three edges (segments): the closest point of `trimesh.triangles.
    closest_point` (Ericson's regions) to rounding, in fewer passes over the arrays (no per-region masks).
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d00, d01, d11 = _squared_norm(ab), np.einsum("ij,ij->i", ab, ac), _squared_norm(ac)
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    # |ab × ac|²: a sliver whose corners are collinear to rounding (sine of its angle below 1e-6)
    # is its edges, as a degenerate triangle is (the projection's weights blow up there)
    denom = d00 * d11 - d01 * d01
    flat = ~(denom > 1e-12 * d00 * d11)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = (d11 * d1 - d01 * d2) / denom
        w = (d00 * d2 - d01 * d1) / denom
        inside = ~flat & (v >= 0) & (w >= 0) & (v + w <= 1)
    v, w = np.where(inside, v, 0.0), np.where(inside, w, 0.0)
    edges = np.minimum(np.minimum(_segment_distance2(ap, ab, d1, d00), _segment_distance2(ap, ac, d2, d11)),
                       _segment_distance2(p - b, c - b))
    return np.where(inside, _squared_norm(ap - v[:, None] * ab - w[:, None] * ac), edges)


def _segment_distance2(offset: np.ndarray, edge: np.ndarray, along: np.ndarray | None = None,
                       length2: np.ndarray | None = None) -> np.ndarray:
    """(m,) squared distance from the points at `offset` (m, 3) from a segment's start to the
    segment `edge` (m, 3); `along` (offset · edge) and `length2` (edge · edge) when known."""
    along = np.einsum("ij,ij->i", offset, edge) if along is None else along
    length2 = _squared_norm(edge) if length2 is None else length2
    t = np.clip(np.divide(along, length2, out=np.zeros_like(along), where=length2 > 0), 0.0, 1.0)
    return _squared_norm(offset - t[:, None] * edge)
