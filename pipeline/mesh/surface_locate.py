"""Where points of one surface lie on a simplified copy of it: the nearest triangle and the
barycentric weights there (closest point on the triangles around the nearest few vertices)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point, points_to_barycentric

#: Nearest simplified vertices whose triangles are searched per point.
NEAREST = 4
#: Points located at once (bounds the candidate arrays).
CHUNK = 200_000


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
    order = np.argsort(faces.reshape(-1), kind="stable")
    owner = order // 3
    counts = np.bincount(faces.reshape(-1), minlength=len(positions))
    start = np.r_[0, np.cumsum(counts)]
    width = int(counts.max()) if len(counts) else 0
    around = np.full((len(positions), width), -1, dtype=np.int64)  # faces around each vertex, padded
    slot = np.arange(len(order)) - np.repeat(start[:-1], counts)
    around[np.repeat(np.arange(len(positions)), counts), slot] = owner
    tree = cKDTree(positions)
    face = np.empty(len(points), dtype=np.int64)
    bary = np.empty((len(points), 3))
    for s in range(0, len(points), CHUNK):
        p = points[s: s + CHUNK]
        _, near = tree.query(p, k=min(NEAREST, len(positions)))
        candidates = np.sort(around[np.asarray(near).reshape(len(p), -1)].reshape(len(p), -1), axis=1)
        candidates[:, 1:][candidates[:, 1:] == candidates[:, :-1]] = -1  # the vertices share faces
        row, col = np.nonzero(candidates >= 0)
        tri = candidates[row, col]
        closest = closest_point(positions[faces[tri]], p[row])
        distance = np.full(candidates.shape, np.inf)
        distance[row, col] = np.einsum("ij,ij->i", closest - p[row], closest - p[row])
        best = np.argmin(distance, axis=1)
        face[s: s + len(p)] = candidates[np.arange(len(p)), best]
        pick = np.zeros(candidates.shape, dtype=bool)
        pick[np.arange(len(p)), best] = True
        chosen = pick[row, col]
        w = points_to_barycentric(positions[faces[tri[chosen]]], closest[chosen])
        w = np.clip(w, 0.0, None)
        bary[s: s + len(p)][row[chosen]] = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    return face, bary
