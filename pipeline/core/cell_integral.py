"""The diffusion profile integrated exactly over each vertex's own surface cell: the self term of
the gather.

A vertex owns a third of each incident triangle: the quadrilateral (vertex, edge midpoint,
centroid, edge midpoint), two triangles with the vertex as apex. Over a triangle with apex v
and far edge PQ, in polar coordinates about v, ∫ Rd(|p - v|) dp = (1/2π) ∫ G(ρ(φ)) dφ with
G(r) = 2π ∫_0^r Rd(s) s ds in closed form (`profile.disc_integral`) and ρ(φ) = ℓ / cos(φ - φ_⊥)
the distance to the edge's line. Gauss-Legendre over φ makes it exact to ~1e-6 for any
triangle shape. A disc of the same area is only right for round cells: on irregular meshes
(long fans of thin triangles) it reaches across neighbours' cells, which then count twice.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.profile import Profile, disc_integral
from sssbake.pipeline.core.scatter_kernels import apex_triangles, triangles_in_plane

#: Gauss-Legendre nodes per sub-triangle of a vertex's own cell (~1e-6), and per triangle seen
#: from a point beside it (~3e-5 typical, 0.6 % at worst with the point near an edge's line).
NODES = 12
NODES_BESIDE = 8
#: Table nodes of G per e-fold of r.
STEPS_PER_E = 200


@dataclass(frozen=True, eq=False)
class Cumulative:
    """G(r) = 2π ∫_0^r Rd(s) s ds, tabulated: ln G linear in ln r on `STEPS_PER_E` nodes per
    e-fold (relative error ~1e-5; tests measure it), G ∝ r² below the first node, G(∞) above
    the last; ~10× cheaper than `profile.disc_integral` for the many nodes of the triangle rules.

    Attributes
    ----------
    log_r0 : float
    log_g : (3, N) float64
        ln G per channel at ln r = log_r0 + i / STEPS_PER_E.
    slope : (3, N) float64
        log_g[:, i + 1] - log_g[:, i] (0 at the last node).
    """

    log_r0: float
    log_g: np.ndarray
    slope: np.ndarray

    @staticmethod
    def build(params: Profile) -> "Cumulative":
        # From far inside the quadratic start to where G has reached R_d to ~1e-6 (the tail
        # beyond r falls as z/r at least as fast as for σ_tr = 0).
        lo = np.log(1e-4 * float(params.z_min.min()))
        hi = np.log(1e6 * float(params.z_max.max()))
        r = np.exp(np.arange(lo, hi + 1.0 / STEPS_PER_E, 1.0 / STEPS_PER_E))
        log_g = np.ascontiguousarray(np.log(np.maximum(disc_integral(r, params), 1e-300)).T)
        return Cumulative(float(lo), log_g, np.diff(log_g, axis=1, append=log_g[:, -1:]))

    def kernel_args(self, nodes: int) -> tuple:
        """(log_r0, log_g, slope, G at the nodes, STEPS_PER_E, Gauss-Legendre nodes and weights of
        `nodes`): the arguments of the compiled triangle rules (`scatter_kernels`)."""
        return (self.log_r0, self.log_g, self.slope, np.exp(self.log_g), float(STEPS_PER_E),
                *np.polynomial.legendre.leggauss(nodes))

    def __call__(self, r: np.ndarray) -> np.ndarray:
        """(...,) radii, mm -> (..., 3)."""
        return np.moveaxis(self.channels(r), 0, -1)

    def channels(self, r: np.ndarray) -> np.ndarray:
        """(...,) radii, mm -> (3, ...): G channel-first, each channel contiguous (the quadrature
        rules reduce over the last axis without an interleaved copy)."""
        u = (np.log(np.maximum(r, 1e-300)) - self.log_r0) * STEPS_PER_E
        # The nodes are evenly spaced in u: index them directly (np.interp would search), one
        # contiguous channel at a time.
        at = np.clip(u, 0.0, self.log_g.shape[1] - 1)
        i = at.astype(np.intp)
        f = at - i
        # Below the table G ∝ r² (a disc of constant Rd(0)); above it G has reached R_d.
        below = np.minimum(u, 0.0) * (2.0 / STEPS_PER_E)
        out = np.empty((3,) + np.shape(r))
        for c, (g, s) in enumerate(zip(self.log_g, self.slope)):
            np.multiply(f, s.take(i), out=out[c])
            out[c] += g.take(i)
            out[c] += below
        return np.exp(out, out=out)


def cell_integral(positions_mm: np.ndarray, faces: np.ndarray, params: Profile) -> np.ndarray:
    """∫ Rd(|p - x_v|) dp over each vertex's barycentric cell.

    Parameters
    ----------
    positions_mm : (n, 3) float64
    faces : (m, 3) int
    params : Profile

    Returns
    -------
    (n, 3) float64, in [0, R_d]; 0 for vertices in no triangle.
    """
    x = np.asarray(positions_mm, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    out = np.zeros((len(x), 3))
    centroid = x[f].mean(axis=1)
    cumulative = Cumulative.build(params)
    halves = [(f[:, k], f[:, (k + j) % 3]) for k in range(3) for j in (1, 2)]  # (vertex, edge's other end)
    # The six sub-triangle sets on threads (the compiled rule needs no GIL: ~1 CPU-s at the 50k
    # dragon, its escape gain's longest step on one thread), summed in a fixed order: the same bits.
    with ThreadPoolExecutor(len(os.sched_getaffinity(0))) as pool:
        values = pool.map(lambda h: apex_triangle(x[h[0]], 0.5 * (x[h[0]] + x[h[1]]), centroid, cumulative), halves)
        for (v, _), value in zip(halves, values):
            for c in range(3):
                out[:, c] += np.bincount(v, weights=value[:, c], minlength=len(x))
    return out


def triangle_integral_in_plane(point: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                               cumulative: "Cumulative") -> np.ndarray:
    """∫ Rd(|p - point|) dp over triangles (a, b, c) from points in their planes.

    The triangle is the signed sum of the three triangles (point, edge) (their orientation
    against the triangle's), each an `apex_triangle` (compiled: `scatter_kernels.triangles_in_plane`).

    Parameters
    ----------
    point, a, b, c : (m, 3) float64, mm
    cumulative : Cumulative
        The material's G.

    Returns
    -------
    (m, 3) float64
    """
    arrays = [np.ascontiguousarray(v, dtype=np.float64) for v in (point, a, b, c)]
    return triangles_in_plane(*arrays, *cumulative.kernel_args(NODES_BESIDE))


def apex_triangle(apex: np.ndarray, p: np.ndarray, q: np.ndarray, cumulative: "Cumulative",
                  nodes: int = NODES) -> np.ndarray:
    """∫ Rd(|x - apex|) dx over triangles (apex, p, q), (m, 3) each point -> (m, 3).

    In polar coordinates about the apex, Gauss-Legendre over the angle of `nodes` nodes; flat
    triangles (the apex on the edge's line) hold nothing (compiled: `scatter_kernels.apex_triangles`)."""
    arrays = [np.ascontiguousarray(v, dtype=np.float64) for v in (apex, p, q)]
    return apex_triangles(*arrays, *cumulative.kernel_args(nodes))
