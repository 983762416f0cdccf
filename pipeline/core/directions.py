"""Light directions spread evenly on the sphere, their triangulation, and interpolation over it.

The prt technique precomputes its integrals for K directions and interpolates at runtime inside
the hull triangle that contains the light direction (Hao & Varshney 2004 §3.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

#: Texels per side of the octahedral lookup (stored as L² uint32: 4 KiB at 32): the walk below
#: is exact within 4 steps from it up to K = 2000 (benchmarks/README.md#direction-lookup).
LOOKUP_SIZE = 32
#: Steps across hull edges from the looked-up triangle (4 enough at L = 32, two spare:
#: benchmarks/README.md#direction-lookup).
WALK_STEPS = 6


@dataclass(frozen=True, eq=False)
class DirectionSet:
    """K unit directions and the triangulation used to interpolate between them.

    Attributes
    ----------
    directions : (K, 3) float64
        Unit vectors (spherical Fibonacci points).
    triangles : (T, 3) int64
        Convex hull of the directions, counter-clockwise seen from outside (T = 2K - 4).
    inverse : (T, 3, 3) float64
        Per triangle, the inverse of the matrix whose columns are its three directions: for ω in
        the triangle's cone, ``inverse[t] @ ω`` is non-negative and proportional to its barycentrics.
    lookup : (L, L) int32
        Triangle containing the direction at each texel centre of the octahedral map
        (`octahedral_texel`); the runtime's first guess.
    neighbours : (T, 3) int32
        Triangle across the edge opposite each corner: where the guess has a negative
        barycentric, the runtime steps there (`WALK_STEPS` times at most).
    """

    directions: np.ndarray
    triangles: np.ndarray
    inverse: np.ndarray
    lookup: np.ndarray
    neighbours: np.ndarray

    @property
    def count(self) -> int:
        return len(self.directions)


def fibonacci_sphere(k: int) -> np.ndarray:
    """(k, 3) float64 spherical Fibonacci points: equal-area bands, golden-angle longitudes."""
    i = np.arange(k, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / k
    rho = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * np.arange(k)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def direction_set(k: int, lookup_size: int = LOOKUP_SIZE) -> DirectionSet:
    """K directions spread evenly on the sphere with their hull triangulation.

    Parameters
    ----------
    k : int
        Number of directions, at least 4.
    lookup_size : int
        Texels per side of the octahedral triangle lookup.
    """
    if k < 4:
        raise ValueError(f"directions: need at least 4 directions to enclose the sphere, got {k}")
    if lookup_size < 1:
        raise ValueError(f"directions: lookup_size must be at least 1, got {lookup_size}")
    d = fibonacci_sphere(k)
    tri = np.asarray(ConvexHull(d).simplices, dtype=np.int64)
    # Orient outward: the centre of the sphere lies behind every face.
    a, b, c = d[tri[:, 0]], d[tri[:, 1]], d[tri[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) < 0
    tri[flip] = tri[flip][:, ::-1]
    inverse = np.linalg.inv(np.stack([d[tri[:, 0]], d[tri[:, 1]], d[tri[:, 2]]], axis=2))
    centres = octahedral_decode((np.stack(np.meshgrid(np.arange(lookup_size), np.arange(lookup_size)), -1)
                                 .reshape(-1, 2) + 0.5) / lookup_size)
    lookup = _containing(inverse, centres).reshape(lookup_size, lookup_size).astype(np.int32)
    return DirectionSet(d, tri, inverse, lookup, _neighbours(tri))


def _neighbours(tri: np.ndarray) -> np.ndarray:
    """(T, 3) triangle sharing the edge opposite each corner of a closed triangulation."""
    t = len(tri)
    # Edge opposite corner c runs from corner c+1 to c+2.
    a = tri[:, [1, 2, 0]].ravel()
    b = tri[:, [2, 0, 1]].ravel()
    key = np.minimum(a, b) * (tri.max() + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    pairs = order.reshape(-1, 2)  # a closed surface has every edge exactly twice
    out = np.empty(3 * t, dtype=np.int64)
    out[pairs[:, 0]] = pairs[:, 1] // 3
    out[pairs[:, 1]] = pairs[:, 0] // 3
    return out.reshape(t, 3).astype(np.int32)


def octahedral_texel(omega: np.ndarray, size: int) -> np.ndarray:
    """(m, 2) int64 texel (column u, row v) of unit directions `omega` (m, 3) in the octahedral map.

    p = ω.xy / (|x| + |y| + |z|); lower hemisphere folded: p = (1 - |p.yx|) · sign(p.xy) with
    sign(0) = +1; texel = clamp(floor((p/2 + 1/2) · size), 0, size - 1). GLSL mirrors this.
    """
    omega = np.atleast_2d(np.asarray(omega, dtype=np.float64))
    p = omega[:, :2] / np.abs(omega).sum(axis=1, keepdims=True)
    sign = np.where(p >= 0.0, 1.0, -1.0)
    folded = (1.0 - np.abs(p[:, ::-1])) * sign
    p = np.where(omega[:, 2:3] < 0.0, folded, p)
    return np.clip(np.floor((p * 0.5 + 0.5) * size), 0, size - 1).astype(np.int64)


def octahedral_decode(uv: np.ndarray) -> np.ndarray:
    """(m, 3) unit directions of octahedral-map coordinates `uv` (m, 2) in [0, 1]²."""
    p = np.asarray(uv, dtype=np.float64) * 2.0 - 1.0
    z = 1.0 - np.abs(p).sum(axis=1)
    sign = np.where(p >= 0.0, 1.0, -1.0)
    xy = np.where(z[:, None] < 0.0, (1.0 - np.abs(p[:, ::-1])) * sign, p)
    v = np.column_stack([xy, z])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _containing(inverse: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Index of the triangle whose cone contains each direction: every triangle is tested, the one
    with the largest smallest barycentric wins (>= 0 exactly in the containing cone)."""
    out = np.empty(len(omega), dtype=np.int64)
    chunk = max(1, (1 << 20) // len(inverse))  # ~25 MB of barycentrics at a time
    for s in range(0, len(omega), chunk):
        b = np.einsum("tij,mj->mti", inverse, omega[s:s + chunk])
        out[s:s + chunk] = b.min(axis=2).argmax(axis=1)
    return out


def interpolation_weights(ds: DirectionSet, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact interpolation over the direction set.

    Parameters
    ----------
    ds : DirectionSet
    omega : (m, 3) float64
        Directions (need not be unit length, must be non-zero).

    Returns
    -------
    index : (m, 3) int64
        Directions of the containing hull triangle.
    weights : (m, 3) float64
        Their non-negative weights, summing to 1 (barycentrics of the central projection).
    """
    omega = _unit(omega)
    t = _containing(ds.inverse, omega)
    return ds.triangles[t], _barycentric(ds.inverse[t], omega)


def lookup_weights(ds: DirectionSet, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What the GLSL runtime computes: the lookup texel's triangle, then up to `WALK_STEPS` steps
    across the edge with the most negative barycentric, then barycentrics clamped at 0.

    Same shapes as `interpolation_weights`.
    """
    omega = _unit(omega)
    uv = octahedral_texel(omega, ds.lookup.shape[0])
    t = ds.lookup[uv[:, 1], uv[:, 0]].astype(np.int64)
    for _ in range(WALK_STEPS):
        b = np.einsum("mij,mj->mi", ds.inverse[t], omega)
        worst = b.argmin(axis=1)
        outside = b[np.arange(len(t)), worst] < 0.0
        t = np.where(outside, ds.neighbours[t, worst], t)
    return ds.triangles[t], _barycentric(ds.inverse[t], omega)


def _barycentric(inverse: np.ndarray, omega: np.ndarray) -> np.ndarray:
    b = np.clip(np.einsum("mij,mj->mi", inverse, omega), 0.0, None)
    total = b.sum(axis=1, keepdims=True)
    return np.where(total > 0.0, b / np.where(total > 0.0, total, 1.0), 1.0 / 3.0)


def _unit(omega: np.ndarray) -> np.ndarray:
    omega = np.atleast_2d(np.asarray(omega, dtype=np.float64))
    length = np.linalg.norm(omega, axis=1, keepdims=True)
    if omega.shape[1] != 3 or not np.all(np.isfinite(omega)) or np.any(length == 0.0):
        raise ValueError(f"directions: need finite non-zero (m, 3) directions, got shape {omega.shape}")
    return omega / length
