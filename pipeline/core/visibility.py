"""Which surface vertices see a light: embree occlusion rays from each vertex towards the light.

Occlusion (any-hit) queries stop at the first blocker, about twice as fast as trimesh's
closest-hit `intersects_any` with the same answer; embree releases the GIL, so threads add to it
(benchmarks/README.md#visibility-rays).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

#: Rays start this fraction of the bounding-box diagonal off the surface along the vertex normal,
#: so they do not hit the triangles around their own vertex.
OFFSET = 1e-4
#: Rays cast per embree call (bounds the memory of origins and directions).
BATCH = 1_000_000
#: Threads casting batches at once.
THREADS = 2


def direction_visibility(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray,
                         directions: np.ndarray, points: np.ndarray | None = None,
                         point_normals: np.ndarray | None = None) -> np.ndarray:
    """Whether each vertex (or each of `points`) sees each directional light unoccluded.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
    normals : (n, 3) float64
        Outward unit vertex normals.
    directions : (K, 3) float64
        Unit directions towards the lights.
    points, point_normals : (p, 3) float64, optional
        Surface points (e.g. texel centres) and their unit normals to test instead of the vertices.

    Returns
    -------
    (n, K) or (p, K) bool
        False where the light is below the point's horizon (n·ω <= 0) or blocked.
    """
    x, scene, offset = _setup(positions, faces, normals)
    if points is not None:
        normals = np.asarray(point_normals, dtype=np.float64)
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape:
            raise ValueError(f"visibility: points and point_normals must be (p, 3), got {points.shape}, {normals.shape}")
        x = points - 0.5 * (np.asarray(positions).min(axis=0) + np.asarray(positions).max(axis=0))
        offset = _offset_length(positions) * normals
    directions = np.asarray(directions, dtype=np.float64)
    facing = np.asarray(normals, dtype=np.float64) @ directions.T > 0.0
    out = np.zeros(facing.shape, dtype=bool)
    vertex, light = np.nonzero(facing)

    def cast(s: int) -> None:
        v, j = vertex[s:s + BATCH], light[s:s + BATCH]
        blocked = scene.run((x[v] + offset[v]).astype(np.float32), directions[j].astype(np.float32),
                            query="OCCLUDED") != -1
        out[v[~blocked], j[~blocked]] = True

    with ThreadPoolExecutor(THREADS) as pool:
        list(pool.map(cast, range(0, len(vertex), BATCH)))
    return out


def point_visibility(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray,
                     light_position: np.ndarray) -> np.ndarray:
    """(n,) bool: whether each vertex sees a point light at `light_position` (3,) unoccluded."""
    x, scene, offset = _setup(positions, faces, normals)
    centre = 0.5 * (np.asarray(positions).min(axis=0) + np.asarray(positions).max(axis=0))
    to_light = np.asarray(light_position, dtype=np.float64) - centre - x
    distance = np.linalg.norm(to_light, axis=1)
    facing = (np.einsum("ij,ij->i", normals, to_light) > 0.0) & (distance > 0.0)
    out = np.zeros(len(x), dtype=bool)
    idx = np.flatnonzero(facing)
    if len(idx):
        d = to_light[idx] / distance[idx, None]
        origins = x[idx] + offset[idx]
        # Blocked only by a hit closer than the light.
        reach = np.maximum(distance[idx] - np.linalg.norm(offset[idx], axis=1), 0.0)
        out[idx] = scene.run(origins.astype(np.float32), d.astype(np.float32), query="OCCLUDED",
                             dists=reach.astype(np.float32)) == -1
    return out


def _setup(positions, faces, normals):
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces)
    normals = np.asarray(normals, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or normals.shape != positions.shape:
        raise ValueError(f"visibility: need positions and normals of shape (n, 3), got {positions.shape}, {normals.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or faces.min() < 0 or faces.max() >= len(positions):
        raise ValueError("visibility: faces must be a non-empty (m, 3) array indexing the positions")
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(normals))):
        raise ValueError("visibility: positions and normals must be finite")
    # Embree works in float32: centring keeps its precision relative to the mesh size.
    centre = 0.5 * (positions.min(axis=0) + positions.max(axis=0))
    x = positions - centre
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, x.astype(np.float32), faces.astype(np.int32))
    return x, scene, _offset_length(positions) * normals


def _offset_length(positions) -> float:
    return OFFSET * float(np.linalg.norm(np.ptp(np.asarray(positions, dtype=np.float64), axis=0)))
