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

import numpy as np

from sssbake.pipeline.core.cell_integral import Cumulative, cell_integral, triangle_integral_in_plane
from sssbake.pipeline.core.profile import Profile, diffuse_reflectance_profile
from sssbake.pipeline.core.disc_average import DiscMean
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

    def weights(self, o: np.ndarray, i: np.ndarray) -> np.ndarray:
        """∫_{cell_i} Rd(|p - x_o|) dp for receivers o and sources i, (m,) each -> (m, 3), mm² · 1/mm²."""
        x = self.positions
        delta = x[o] - x[i]
        d = np.sqrt(np.einsum("ij,ij->i", delta, delta))
        radius = np.sqrt(self.area / np.pi)
        out = np.empty((len(o), 3))
        # Most pairs of a gather are far from small sources: the point value, before any of
        # the finer cases (`DiscMean.is_point`, the same rule as inside `DiscMean`).
        point = self.disc.is_point(d, radius[i]) & (o != i)
        out[point] = diffuse_reflectance_profile(d[point], self.disc.params) * self.area[i[point], None]
        rest = np.flatnonzero(~point)
        if len(rest):
            out[rest] = self._close(o[rest], i[rest], delta[rest], d[rest], radius)
        return out

    def _close(self, o: np.ndarray, i: np.ndarray, delta: np.ndarray, d: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """`weights` of pairs that are not far from small sources (offsets x_o - x_i, distances
        and every vertex's disc radius given)."""
        x = self.positions
        out = np.empty((len(o), 3))
        itself = o == i
        out[itself] = self.own[o[itself]]
        split = ~itself & (d < ZONE * (radius[o] + radius[i]))
        whole = ~itself & ~split
        if np.any(whole):
            h = np.abs(np.einsum("ij,ij->i", delta[whole], self.normals[i[whole]]))
            out[whole] = self.disc(d[whole], radius[i[whole]], h) * self.area[i[whole], None]
        if np.any(split):
            pair = np.flatnonzero(split)
            count = self.sub_ptr[i[pair] + 1] - self.sub_ptr[i[pair]]
            which = np.repeat(np.arange(len(pair)), count)
            sub = np.repeat(self.sub_ptr[i[pair]] - (np.cumsum(count) - count), count) + np.arange(len(which))
            receiver = o[pair][which]
            value = np.empty((len(sub), 3))
            shared = (self.sub_face[sub] == receiver[:, None]).any(axis=1)
            if np.any(shared):
                tri = self.sub_corners[sub[shared]]
                value[shared] = triangle_integral_in_plane(x[receiver[shared]], tri[:, 0], tri[:, 1], tri[:, 2],
                                                           self.cumulative)
            apart = ~shared
            ds = x[receiver[apart]] - self.sub_corners[sub[apart]].mean(axis=1)
            dist = np.sqrt(np.einsum("ij,ij->i", ds, ds))
            h = np.abs(np.einsum("ij,ij->i", ds, self.sub_normal[sub[apart]]))
            value[apart] = self.disc(dist, np.sqrt(self.sub_area[sub[apart]] / np.pi), h) * self.sub_area[sub[apart], None]
            # Sum each pair's run of sub-triangles (`which` ascends; pairs without any keep 0).
            out[pair] = 0.0
            has = np.flatnonzero(count)
            out[pair[has]] = np.add.reduceat(value, (np.cumsum(count) - count)[has], axis=0)
        return out
