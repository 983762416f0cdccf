"""What one vertex's area sends to a receiver: ∫_{cell_i} Rd(|p - x_o|) dp, the weight of
source i's irradiance in receiver o's gather, for the exact pairs of the gather and of the
offline reference.

Each vertex owns a third of its triangles: its barycentric cell, the union of the sub-triangles
(vertex, edge midpoint, centroid), six per triangle, all of equal area. The cells tile the
surface; equal-area discs do not: on irregular meshes (fans of long triangles) a large disc
reaches across its neighbours' cells, which then count twice (discs overestimate a vertex's own
cell integral, and q across resolutions agrees half as well:
benchmarks/README.md#near-field-cell-integrals). So:

- the receiver's own cell is integrated exactly (`cell_integral`);
- sources close to the receiver (d < `ZONE`·(a_o + a_i), a = sqrt(ΔA/π)) are their six-per-
  triangle sub-triangles: integrated exactly where they share a triangle with the receiver
  (`cell_integral.triangle_integral_in_plane`; the kernel is steepest there, and a disc misses
  the corner that touches the receiver's cell), else each a disc of its area in its triangle's
  plane (`DiscMean`);
- farther sources are one disc in their tangent plane, which is accurate there to second order.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from sssbake.pipeline.core.cell_integral import NODES_BESIDE, Cumulative, cell_integral
from sssbake.pipeline.core.disc_average import NODES as DISC_NODES, _POLAR_RULE, DiscMean
from sssbake.pipeline.core.profile import Profile
from sssbake.pipeline.core.scatter_kernels import RADIAL_DECAYS, pair_weights, radial_table
from sssbake.pipeline.core.surface import triangle_areas

#: Sources within this many (a_o + a_i) of the receiver are split into sub-triangles.
ZONE = 1.5


@dataclass(frozen=True, eq=False)
class NearField:
    """Attributes
    ----------
    positions : (n, 3) float64
        mm.
    area : (n,) float64
        Cell areas, mm².
    normals : (n, 3) float64
    own : (n, 3) float64
        ∫ Rd over each vertex's own cell.
    sub_ptr : (n + 1,) int64
        Sub-triangles of vertex i are sub_*[sub_ptr[i]:sub_ptr[i + 1]].
    sub_corners : (s, 3, 3) float64
        Each sub-triangle's vertex, edge midpoint and triangle centroid.
    sub_normal : (s, 3) float64
    sub_area : (s,) float64
    sub_face : (s, 3) int64
        The vertices of the triangle it lies in.
    cumulative : Cumulative
        The material's G(r), for the exact triangle integrals.
    disc : DiscMean
    """

    positions: np.ndarray
    area: np.ndarray
    normals: np.ndarray
    own: np.ndarray
    sub_ptr: np.ndarray
    sub_corners: np.ndarray
    sub_normal: np.ndarray
    sub_area: np.ndarray
    sub_face: np.ndarray
    cumulative: Cumulative
    disc: DiscMean

    @staticmethod
    def build(positions_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray, params: Profile) -> "NearField":
        """Parameters
        ----------
        positions_mm : (n, 3) float64
        faces : (m, 3) int
        normals : (n, 3) float64
            Unit vertex normals (the plane of a source's disc).
        params : Profile
        """
        x = np.asarray(positions_mm, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        n = len(x)
        tri_area = triangle_areas(x, f) if len(f) else np.zeros(0)
        corners = x[f]  # (m, 3, 3)
        centroid = corners.mean(axis=1)
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(cross, axis=1, keepdims=True)
        face_normal = np.divide(cross, length, out=np.zeros_like(cross), where=length > 0)
        owner, sub = [], []
        for k in range(3):
            for other in ((k + 1) % 3, (k + 2) % 3):
                owner.append(f[:, k])
                sub.append(np.stack([corners[:, k], 0.5 * (corners[:, k] + corners[:, other]), centroid], axis=1))
        owner = np.concatenate(owner)
        by_owner = np.argsort(owner, kind="stable")
        sub_corners = np.concatenate(sub)[by_owner]
        sub_normal = np.tile(face_normal, (6, 1))[by_owner]
        sub_area = np.tile(tri_area / 6.0, 6)[by_owner]
        sub_face = np.tile(f, (6, 1))[by_owner]
        sub_ptr = np.r_[0, np.cumsum(np.bincount(owner, minlength=n))]
        area = np.bincount(owner, weights=np.tile(tri_area / 6.0, 6), minlength=n)
        radii = np.sqrt(np.r_[area, sub_area] / np.pi)
        return NearField(x, area, np.asarray(normals, dtype=np.float64), cell_integral(x, f, params), sub_ptr,
                         sub_corners, sub_normal, sub_area, sub_face, Cumulative.build(params), DiscMean.build(params, radii))

    @cached_property
    def kernel_args(self) -> tuple:
        """(field, weight, depth, sigma, disc, cumulative): this field as the arguments of the
        compiled `scatter_kernels.pair_weight` (numba takes arrays, not dataclasses)."""
        p = self.disc.params
        radius = np.sqrt(self.area / np.pi)
        field = (self.positions, self.area, radius, self.normals, self.own, self.sub_ptr, self.sub_corners,
                 self.sub_normal, self.sub_area, self.sub_face, ZONE)
        # The radial table from well inside the shallowest pole to the object's size (no pair
        # is farther apart; measured from the centroid, so that a rotated mesh reads the same
        # table) or RADIAL_DECAYS decay lengths, whichever is nearer.
        r_lo = 1e-4 * float(p.z_min.min())
        x = self.positions
        size = 2.0 * float(np.sqrt(((x - x.mean(axis=0)) ** 2).sum(axis=1).max())) if len(x) else 0.0
        r_hi = max(min(size, RADIAL_DECAYS / max(float(p.sigma_tr.max()), 1e-300)), 4.0 * r_lo)
        disc = (self.disc.log_a0, self.disc.table, *np.polynomial.legendre.leggauss(DISC_NODES), *_POLAR_RULE,
                float(p.z_min.min()), float(p.sigma_tr.max()), radial_table(p.weight, p.depth, p.sigma, r_lo, r_hi),
                self.disc.a, self.disc.t)
        return field, p.weight, p.depth, p.sigma, disc, self.cumulative.kernel_args(NODES_BESIDE)

    def weights(self, o: np.ndarray, i: np.ndarray) -> np.ndarray:
        """∫_{cell_i} Rd(|p - x_o|) dp for receivers o and sources i, (m,) each -> (m, 3), mm² · 1/mm².

        Pairs far from small sources take the point value; the receiver's own cell its exact
        integral; sources within `ZONE` their sub-triangles; the rest a disc in the source's
        tangent plane (`scatter_kernels.pair_weight`)."""
        o = np.ascontiguousarray(o, dtype=np.int64)
        i = np.ascontiguousarray(i, dtype=np.int64)
        return pair_weights(o, i, *self.kernel_args)
