"""How an atlas sits on a mesh's welded surface: every surface face's UVs (in texels), its chart and
its atlas vertices, and the face across each of its edges.

Surface faces are the primitives' faces concatenated in order (`clean.weld_surface`), which is also
the order xatlas keeps within each atlas part, corner for corner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas


@dataclass(frozen=True, eq=False)
class AtlasSurface:
    """Attributes
    ----------
    face_uv : (f, 3, 2) float64
        Corner UVs in texel units (x = u · width, y = v · height).
    face_chart : (f,) int64
        Chart of each face: faces joined through shared atlas vertices.
    face_atlas : (f, 3) int64
        Atlas vertex of each corner, numbered over all parts.
    opposite : (f, 3) int64
        The face across edge (corner k, corner k+1), through welded vertices; -1 on a boundary.
    part_face_offset : (parts + 1,) int64
        Surface face of part p's face i: ``part_face_offset[p] + i``.
    width, height : int
    """

    face_uv: np.ndarray
    face_chart: np.ndarray
    face_atlas: np.ndarray
    opposite: np.ndarray
    part_face_offset: np.ndarray
    width: int
    height: int

    def seam(self, faces: np.ndarray) -> np.ndarray:
        """(m, 3) bool: which edges of `faces` (m,) have a neighbour stored elsewhere in the atlas
        (another chart, or other atlas vertices of the same chart)."""
        other = self.opposite[faces]
        has = other >= 0
        mine = self.face_atlas[faces]
        out = np.zeros(other.shape, dtype=bool)
        for k in range(3):
            f, g = np.flatnonzero(has[:, k]), other[has[:, k], k]
            a, b = mine[f, k], mine[f, (k + 1) % 3]
            theirs = self.face_atlas[g]
            shared = ((theirs == a[:, None]).any(axis=1) & (theirs == b[:, None]).any(axis=1)
                      & (self.face_chart[g] == self.face_chart[faces[f]]))
            out[f, k] = ~shared
        return out


def atlas_surface(atlas: Atlas, surface: Surface) -> AtlasSurface:
    """Map `atlas` (over the mesh's primitives) onto its welded `surface`."""
    uv, atlas_ids, offsets, start = [], [], [0], 0
    for part in atlas.parts:
        uv.append(part.uvs[part.faces] * (atlas.width, atlas.height))
        atlas_ids.append(part.faces + start)
        start += len(part.uvs)
        offsets.append(offsets[-1] + len(part.faces))
    face_uv = np.concatenate(uv)
    face_atlas = np.concatenate(atlas_ids)
    if len(face_uv) != len(surface.faces):
        raise ValueError(f"atlas: {len(face_uv)} atlas faces for {len(surface.faces)} surface faces; "
                         "the atlas was made for other primitives")
    m = len(face_atlas)
    incidence = coo_matrix((np.ones(3 * m), (np.repeat(np.arange(m), 3), face_atlas.reshape(-1))),
                           shape=(m, start)).tocsr()
    _, chart = connected_components(incidence @ incidence.T, directed=False)
    return AtlasSurface(face_uv, chart.astype(np.int64), face_atlas, _opposite(surface.faces, len(surface.positions)),
                        np.asarray(offsets, dtype=np.int64), atlas.width, atlas.height)


def _opposite(faces: np.ndarray, n: int) -> np.ndarray:
    """(f, 3) the face across each edge through welded vertices (-1: none). On a non-manifold
    edge each face sees the next one sharing it."""
    m = len(faces)
    a = faces.reshape(-1)
    b = np.roll(faces, -1, axis=1).reshape(-1)
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    start = np.r_[0, np.flatnonzero(np.diff(sorted_key)) + 1]
    count = np.diff(np.r_[start, len(key)])
    group = np.repeat(np.arange(len(start)), count)
    rank = np.arange(len(key)) - start[group]
    partner = start[group] + (rank + 1) % count[group]  # the next half-edge of the same edge, cyclic
    out = np.full(3 * m, -1, dtype=np.int64)
    shared = count[group] > 1
    out[order[shared]] = order[partner[shared]] // 3
    return out.reshape(m, 3)
