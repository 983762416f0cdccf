"""The dipole profile integrated exactly over each vertex's own surface cell: the self term of
the gather.

A vertex owns a third of each incident triangle: the quadrilateral (vertex, edge midpoint,
centroid, edge midpoint), two triangles with the vertex as apex. Over a triangle with apex v
and far edge PQ, in polar coordinates about v, ∫ Rd(|p - v|) dp = (1/2π) ∫ G(ρ(φ)) dφ with
G(r) = 2π ∫_0^r Rd(s) s ds in closed form (`dipole.disc_integral`) and ρ(φ) = ℓ / cos(φ - φ_⊥)
the distance to the edge's line. Gauss-Legendre over φ makes it exact to ~1e-6 for any
triangle shape. A disc of the same area is only right for round cells: on irregular meshes
(long fans of thin triangles) it reaches across neighbours' cells, which then count twice.
"""

from __future__ import annotations

import numpy as np

from .dipole import DipoleParams, disc_integral

#: Gauss-Legendre nodes per sub-triangle.
NODES = 12


def cell_integral(positions_mm: np.ndarray, faces: np.ndarray, params: DipoleParams) -> np.ndarray:
    """∫ Rd(|p - x_v|) dp over each vertex's barycentric cell.

    Parameters
    ----------
    positions_mm : (n, 3) float64
    faces : (m, 3) int
    params : DipoleParams

    Returns
    -------
    (n, 3) float64, in [0, R_d]; 0 for vertices in no triangle.
    """
    x = np.asarray(positions_mm, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    out = np.zeros((len(x), 3))
    centroid = x[f].mean(axis=1)
    for k in range(3):
        v = f[:, k]
        for other in (f[:, (k + 1) % 3], f[:, (k + 2) % 3]):
            value = apex_triangle(x[v], 0.5 * (x[v] + x[other]), centroid, params)
            for c in range(3):
                out[:, c] += np.bincount(v, weights=value[:, c], minlength=len(x))
    return out


def triangle_integral_in_plane(point: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                               params: DipoleParams) -> np.ndarray:
    """∫ Rd(|p - point|) dp over triangles (a, b, c) from points in their planes.

    The triangle is the signed sum of the three triangles (point, edge) (their orientation
    against the triangle's), each an `apex_triangle`.

    Parameters
    ----------
    point, a, b, c : (m, 3) float64, mm
    params : DipoleParams

    Returns
    -------
    (m, 3) float64
    """
    normal = np.cross(b - a, c - a)
    out = np.zeros((len(point), 3))
    for p, q in ((a, b), (b, c), (c, a)):
        sign = np.sign(np.einsum("ij,ij->i", np.cross(p - point, q - point), normal))
        out += sign[:, None] * apex_triangle(point, p, q, params)
    return out


def apex_triangle(apex: np.ndarray, p: np.ndarray, q: np.ndarray, params: DipoleParams) -> np.ndarray:
    """∫ Rd(|x - apex|) dx over triangles (apex, p, q), (m, 3) each point -> (m, 3)."""
    nodes, weights = np.polynomial.legendre.leggauss(NODES)
    e1, e2 = p - apex, q - apex
    l1, l2 = np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1)
    length = np.linalg.norm(q - p, axis=1)
    ok = (l1 > 0) & (l2 > 0) & (length > 0)
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", e1, e2) / np.where(ok, l1 * l2, 1.0), -1.0, 1.0))
    # Distance from the apex to the edge's line, and the angle from e1 to its foot (negative
    # when the foot lies beyond p, the angle at p being obtuse).
    foot = np.where(ok, np.linalg.norm(np.cross(e1, e2), axis=1) / np.where(ok, length, 1.0), 0.0)
    to_foot = np.arccos(np.clip(np.where(ok, foot / np.where(ok, l1, 1.0), 1.0), -1.0, 1.0))
    to_foot = np.where(np.einsum("ij,ij->i", -e1, q - p) >= 0.0, to_foot, -to_foot)
    phi = 0.5 * angle[:, None] * (nodes[None, :] + 1.0)  # (m, NODES) from e1 towards e2
    rho = foot[:, None] / np.maximum(np.cos(phi - to_foot[:, None]), 1e-12)
    value = np.einsum("k,mkc->mc", weights, disc_integral(rho, params)) * (0.5 * angle / (2.0 * np.pi))[:, None]
    value[~ok] = 0.0
    return value
