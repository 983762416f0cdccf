"""Border texels: the surface across a chart's seams, unfolded into the chart's gutter, so that a
texel's k × k kernel near a seam still sees the surface (and the light) beyond it.

Lensch et al. (§5.1) add a border of adjacent triangles to each chart before packing. xatlas packs
charts without one, so the border is made afterwards in the gutter: starting at every seam edge,
the triangle across it is unfolded into the chart's UV plane (its shape kept, scaled like the edge),
then the triangles across its other two edges, ring after ring, while they stay within `reach`
texels of the seam. Each gutter texel belongs to the chart of its nearest covered texel
(chessboard distance), and only that chart's border triangles may claim it, so two charts whose
gutters meet split the gutter instead of overwriting each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas_surface import AtlasSurface
from sssbake.pipeline.mesh.texels import rasterize_atlas

#: Rings of triangles unfolded at most (a ring of sub-texel triangles gains little distance).
MAX_RINGS = 24
#: Unfolded triangles rasterised at once (bounds the rasteriser's per-corner copies to ~100 MB).
BATCH = 1 << 18


@dataclass(frozen=True, eq=False)
class BorderTexels:
    """Attributes
    ----------
    pixels : (b,) int64
        ``row · width + col``, strictly increasing; none is covered.
    faces : (b,) int64
        Surface face the texel's point lies in.
    barycentric : (b, 3) float64
        The point's weights on ``surface.faces[faces]``.
    chart : (b,) int64
        Chart whose gutter holds the texel.
    areas : (b,) float64
        Surface area the texel stands for, mesh units².
    triangles : int
        Border triangles unfolded.
    """

    pixels: np.ndarray
    faces: np.ndarray
    barycentric: np.ndarray
    chart: np.ndarray
    areas: np.ndarray
    triangles: int


def border_texels(layout: AtlasSurface, surface: Surface, covered_pixels: np.ndarray, covered_chart: np.ndarray,
                  reach: int) -> BorderTexels:
    """Unfold the triangles across every seam into the gutter, within `reach` texels.

    Parameters
    ----------
    layout : AtlasSurface
    surface : Surface
    covered_pixels : (s,) int64
        Covered texels, ``row · width + col``.
    covered_chart : (s,) int64
        Their charts.
    reach : int
        Chessboard distance in texels from the nearest covered texel that border texels may lie.
    """
    w, h = layout.width, layout.height
    covered = np.zeros(h * w, dtype=bool)
    covered[covered_pixels] = True
    chart_image = np.full(h * w, -1, dtype=np.int64)
    chart_image[covered_pixels] = covered_chart
    if reach < 1 or not covered.any():
        return _empty()
    distance, (near_row, near_col) = ndimage.distance_transform_cdt(~covered.reshape(h, w), metric="chessboard",
                                                                    return_indices=True)
    distance = distance.reshape(-1)
    owner = chart_image[(near_row * w + near_col).reshape(-1)]

    tri_chart, tri_faces, uvs = _unfold(layout, surface, reach)
    if not len(tri_faces):
        return _empty()

    def accept(pixels: np.ndarray, tri: np.ndarray) -> np.ndarray:
        return ~covered[pixels] & (distance[pixels] <= reach) & (owner[pixels] == tri_chart[tri])

    # In batches of triangles (a 150k-vertex mesh unfolds millions, and the rasteriser's per-corner
    # copies of them took 2.5 GB at once); each batch keeps the first of its triangles over a texel,
    # and the batches, in triangle order, the first batch's: as one rasterisation of all would.
    def batch(lo: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        faces = surface.faces[tri_faces[lo: lo + BATCH]]
        flat = np.arange(3 * len(faces)).reshape(-1, 3)
        samples = rasterize_atlas([(uvs[lo: lo + BATCH].reshape(-1, 2) / (w, h), flat,
                                    surface.positions[faces].reshape(-1, 3), surface.normals[faces].reshape(-1, 3))],
                                  w, h, lambda pixels, tri: accept(pixels, tri + lo))
        return samples.rows * w + samples.cols, samples.face + lo, samples.barycentric, samples.areas

    pixel, face, bary, area = zip(*map(batch, range(0, len(tri_faces), BATCH)))
    pixel, first = np.unique(np.concatenate(pixel), return_index=True)
    face = np.concatenate(face)[first]
    return BorderTexels(pixel, tri_faces[face], np.concatenate(bary)[first], tri_chart[face],
                        np.concatenate(area)[first], len(tri_faces))


def _empty() -> BorderTexels:
    return BorderTexels(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64),
                        np.zeros(0), 0)


def _unfold(layout: AtlasSurface, surface: Surface, reach: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unfolded triangles, nearest rings first.

    Returns
    -------
    chart : (t,) int64
        The chart each triangle borders.
    face : (t,) int64
        The surface face it copies.
    uvs : (t, 3, 2) float64
        Texel-unit UVs of the face's corners in the chart's frame, in ``surface.faces`` order.
    """
    faces, x = surface.faces, surface.positions
    m = len(faces)
    seam = layout.seam(np.arange(m))
    f, k = np.nonzero(seam)
    fuv = layout.face_uv
    frontier = {
        "chart": layout.face_chart[f], "face": layout.opposite[f, k],
        "a": faces[f, k], "b": faces[f, (k + 1) % 3],
        "uva": fuv[f, k], "uvb": fuv[f, (k + 1) % 3], "uvo": fuv[f, (k + 2) % 3],
    }
    frontier["o0"], frontier["o1"] = frontier["uva"], frontier["uvb"]
    visited = np.sort(layout.face_chart * m + np.arange(m))
    out_chart, out_face, out_uv = [], [], []
    for _ in range(MAX_RINGS):
        if not len(frontier["face"]):
            break
        key = frontier["chart"] * m + frontier["face"]
        _, first = np.unique(key, return_index=True)
        fresh = first[~_contains(visited, key[first])]
        if not len(fresh):
            break
        frontier = {name: value[fresh] for name, value in frontier.items()}
        visited = np.sort(np.concatenate([visited, key[fresh]]), kind="stable")  # fresh keys are new and distinct
        g = frontier["face"]
        corner = faces[g]
        is_a = corner == frontier["a"][:, None]
        is_b = corner == frontier["b"][:, None]
        is_x = ~(is_a | is_b)
        good = is_a.any(axis=1) & is_b.any(axis=1) & (is_x.sum(axis=1) == 1)
        frontier = {name: value[good] for name, value in frontier.items()}
        g, corner, is_a, is_b, is_x = g[good], corner[good], is_a[good], is_b[good], is_x[good]
        ia, ib, ix = is_a.argmax(axis=1), is_b.argmax(axis=1), is_x.argmax(axis=1)
        rows = np.arange(len(g))
        pa, pb, px = x[frontier["a"]], x[frontier["b"]], x[corner[rows, ix]]
        edge = pb - pa
        length2 = np.einsum("ij,ij->i", edge, edge)
        ok = length2 > 0
        t = np.einsum("ij,ij->i", px - pa, edge) / np.where(ok, length2, 1.0)
        lift = np.linalg.norm(np.cross(px - pa, edge), axis=1) / np.where(ok, length2, 1.0)
        e = frontier["uvb"] - frontier["uva"]
        perp = np.column_stack([-e[:, 1], e[:, 0]])
        rel = frontier["uvo"] - frontier["uva"]
        side = np.where(e[:, 0] * rel[:, 1] - e[:, 1] * rel[:, 0] > 0, -1.0, 1.0)
        uvx = frontier["uva"] + t[:, None] * e + (side * lift)[:, None] * perp
        uv = np.empty((len(g), 3, 2))
        uv[rows, ia], uv[rows, ib], uv[rows, ix] = frontier["uva"], frontier["uvb"], uvx
        keep = ok & np.all(np.isfinite(uvx), axis=1)
        out_chart.append(frontier["chart"][keep])
        out_face.append(g[keep])
        out_uv.append(uv[keep])
        # Go on across the two new edges while the new corner is still near the seam it came from.
        near = keep & (_segment_distance(uvx, frontier["o0"], frontier["o1"]) <= reach + 1.0)
        nxt = {name: [] for name in frontier}
        for other in (ib, ia):  # edges {a, x} and {x, b}: the edge of g without corner `other`
            kk = (other + 1) % 3
            across = layout.opposite[g, kk]
            sel = near & (across >= 0)
            s, kk = np.flatnonzero(sel), kk[sel]
            for name, value in (("chart", frontier["chart"][s]), ("face", across[s]), ("a", corner[s, kk]),
                                ("b", corner[s, (kk + 1) % 3]), ("uva", uv[s, kk]), ("uvb", uv[s, (kk + 1) % 3]),
                                ("uvo", uv[s, other[s]]), ("o0", frontier["o0"][s]), ("o1", frontier["o1"][s])):
                nxt[name].append(value)
        frontier = {name: np.concatenate(parts) for name, parts in nxt.items()}
    if not out_face:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3, 2))
    return np.concatenate(out_chart), np.concatenate(out_face), np.concatenate(out_uv)


def _contains(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    at = np.searchsorted(sorted_keys, keys)
    return (at < len(sorted_keys)) & (sorted_keys[np.minimum(at, len(sorted_keys) - 1)] == keys)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m,) distance from points p to segments a-b, (m, 2) each."""
    ab = b - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)
