"""Texel sampling of a texture atlas: which surface point every covered texel stands for.

UV convention (glTF, as produced by `sssbake.pipeline.mesh.atlas`): origin at the top-left of the
image, v down; texel ``(row, col)`` has its centre at ``((col + 0.5) / width, (row + 0.5) / height)``
and covers ``1 / (width · height)`` of UV space. A texel is covered when its centre lies inside (or
on the edge of) a triangle in UV space; a centre on a shared edge goes to one triangle only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sssbake.pipeline.core.errors import SssbakeError

# Upper bound on candidate texels tested at once; bounds peak memory to ~100 MB.
CHUNK = 1_000_000
# Barycentric tolerance (texel units) so centres exactly on an edge are not lost to rounding.
EDGE_TOLERANCE = 1e-9


class TexelError(SssbakeError, ValueError):
    """Input the texel rasteriser cannot work with."""


@dataclass(frozen=True, eq=False)
class TexelSamples:
    """One sample per covered texel, sorted by ``row * width + col``.

    Attributes
    ----------
    rows, cols : (s,) int64
        Texel coordinates; row 0 is the top of the image (v = 0).
    part : (s,) int64
        Index of the part the texel's triangle belongs to.
    face : (s,) int64
        The triangle within its part.
    barycentric : (s, 3) float64
        Weights of the triangle's three corners at the texel centre.
    positions : (s, 3) float64
        Interpolated 3-D position, mesh units.
    normals : (s, 3) float64
        Interpolated vertex normal, normalised (the face normal where the interpolation cancels).
    areas : (s,) float64
        Surface area the texel stands for: triangle area × the texel's share of the triangle's
        UV area, mesh units².
    width, height : int
    """

    rows: np.ndarray
    cols: np.ndarray
    part: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    areas: np.ndarray
    width: int
    height: int

    @property
    def mask(self) -> np.ndarray:
        """(height, width) bool: texels covered by a triangle."""
        mask = np.zeros((self.height, self.width), dtype=bool)
        mask[self.rows, self.cols] = True
        return mask


def rasterize_atlas(
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    width: int,
    height: int,
    accept=None,
) -> TexelSamples:
    """Find the surface point behind every texel whose centre lies inside an atlas triangle.

    Parameters
    ----------
    parts : list of (uvs (n_i, 2) float64, faces (m_i, 3) int64, positions (n_i, 3) float64,
            normals (n_i, 3) float64)
        Per part, the atlas vertices (e.g. ``positions[atlas_part.vmapping]``) and their UVs in
        [0, 1], glTF convention.
    width, height : int
        Atlas size in texels.
    accept : callable, optional
        ``accept(pixels (m,) int64, triangles (m,) int64) -> (m,) bool``: which candidate samples
        may claim their texel (triangles numbered over all parts in order), before the first
        triangle over a texel takes it.

    Returns
    -------
    TexelSamples
    """
    if width < 1 or height < 1:
        raise TexelError(f"texels: atlas size must be at least 1 × 1, got {width} × {height}")
    if not parts:
        raise TexelError("texels: no parts given; pass at least one (uvs, faces, positions, normals)")
    uv_corners, xyz_corners, normal_corners, part_of, face_of = [], [], [], [], []
    for i, (uvs, faces, positions, normals) in enumerate(parts):
        uvs = np.asarray(uvs, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64)
        positions = np.asarray(positions, dtype=np.float64)
        normals = np.asarray(normals, dtype=np.float64)
        n = len(uvs)
        if uvs.shape != (n, 2) or positions.shape != (n, 3) or normals.shape != (n, 3):
            raise TexelError(
                f"texels: part {i} needs uvs (n, 2), positions (n, 3), normals (n, 3) with one n, "
                f"got {uvs.shape}, {positions.shape}, {normals.shape}"
            )
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and (faces.min() < 0 or faces.max() >= n)):
            raise TexelError(f"texels: part {i} faces must be (m, 3) indices into its {n} atlas vertices")
        uv_corners.append(uvs[faces] * (width, height))
        xyz_corners.append(positions[faces])
        normal_corners.append(normals[faces])
        part_of.append(np.full(len(faces), i, dtype=np.int64))
        face_of.append(np.arange(len(faces), dtype=np.int64))
    tri_uv = np.concatenate(uv_corners)
    tri_xyz = np.concatenate(xyz_corners)
    tri_normal = np.concatenate(normal_corners)
    tri_part = np.concatenate(part_of)
    tri_face = np.concatenate(face_of)
    if not (np.isfinite(tri_uv).all() and np.isfinite(tri_xyz).all()):
        raise TexelError("texels: uvs or positions contain NaN or Inf; clean the mesh first")

    # Texel centres sit at half-integer pixel coordinates: col c covers x = c + 0.5.
    # corner by corner: a reduction over the 3-long axis is four times slower on millions of triangles
    lo = np.ceil(np.minimum(np.minimum(tri_uv[:, 0], tri_uv[:, 1]), tri_uv[:, 2]) - 0.5).astype(np.int64)
    hi = np.floor(np.maximum(np.maximum(tri_uv[:, 0], tri_uv[:, 1]), tri_uv[:, 2]) - 0.5).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, (width - 1, height - 1))
    extent = np.maximum(hi - lo + 1, 0)
    counts = extent[:, 0] * extent[:, 1]

    e0 = tri_uv[:, 1] - tri_uv[:, 0]
    e1 = tri_uv[:, 2] - tri_uv[:, 0]
    uv_area2 = e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0]
    counts[np.abs(uv_area2) == 0.0] = 0
    cross = np.cross(tri_xyz[:, 1] - tri_xyz[:, 0], tri_xyz[:, 2] - tri_xyz[:, 0])
    xyz_area = 0.5 * np.linalg.norm(cross, axis=1)

    found_tri, found_pixel, found_bary = [], [], []
    cumulative = np.cumsum(counts)
    bounds = np.searchsorted(cumulative, np.arange(CHUNK, cumulative[-1] if len(cumulative) else 0, CHUNK))
    for chunk in np.split(np.arange(len(counts)), np.unique(bounds)):
        tri = np.repeat(chunk, counts[chunk])
        if not len(tri):
            continue
        start = np.cumsum(counts[chunk]) - counts[chunk]
        local = np.arange(len(tri)) - np.repeat(start, counts[chunk])
        nx = extent[tri, 0]
        col = lo[tri, 0] + local % nx
        row = lo[tri, 1] + local // nx
        rel_x = col + 0.5 - tri_uv[tri, 0, 0]
        rel_y = row + 0.5 - tri_uv[tri, 0, 1]
        inv = 1.0 / uv_area2[tri]
        b1 = (rel_x * e1[tri, 1] - rel_y * e1[tri, 0]) * inv
        b2 = (e0[tri, 0] * rel_y - e0[tri, 1] * rel_x) * inv
        b0 = 1.0 - b1 - b2
        inside = (b0 >= -EDGE_TOLERANCE) & (b1 >= -EDGE_TOLERANCE) & (b2 >= -EDGE_TOLERANCE)
        if accept is not None:
            inside &= accept(row * width + col, tri)
        found_tri.append(tri[inside])
        found_pixel.append(row[inside] * width + col[inside])
        found_bary.append(np.stack([b0[inside], b1[inside], b2[inside]], axis=1))

    if found_tri:
        tri = np.concatenate(found_tri)
        pixel = np.concatenate(found_pixel)
        bary = np.clip(np.concatenate(found_bary), 0.0, 1.0)
        bary /= bary.sum(axis=1, keepdims=True)
    else:
        tri = np.zeros(0, dtype=np.int64)
        pixel = np.zeros(0, dtype=np.int64)
        bary = np.zeros((0, 3))
    pixel, first = np.unique(pixel, return_index=True)
    tri, bary = tri[first], bary[first]

    positions = np.einsum("sk,skd->sd", bary, tri_xyz[tri])
    normals = np.einsum("sk,skd->sd", bary, tri_normal[tri])
    length = np.linalg.norm(normals, axis=1)
    cancelled = ~(length > 1e-12)
    normals[cancelled] = cross[tri[cancelled]]
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), np.finfo(float).tiny)

    return TexelSamples(
        rows=pixel // width,
        cols=pixel % width,
        part=tri_part[tri],
        face=tri_face[tri],
        barycentric=bary,
        positions=positions,
        normals=normals,
        areas=xyz_area[tri] / (0.5 * np.abs(uv_area2[tri])),
        width=int(width),
        height=int(height),
    )


def dilate(image: np.ndarray, mask: np.ndarray, pixels: int) -> np.ndarray:
    """Fill uncovered texels within ``pixels`` of a covered one with that nearest texel's value.

    Keeps bilinear filtering and mip-mapping at chart borders from blending in background.

    Parameters
    ----------
    image : (H, W, C) or (H, W) array
    mask : (H, W) bool
        Covered texels.
    pixels : int
        Largest Euclidean distance, in texels, that gets filled.

    Returns
    -------
    (H, W, C) or (H, W) array
        A copy of ``image``, covered texels unchanged.
    """
    image = np.asarray(image)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != image.shape[:2]:
        raise TexelError(f"texels: dilate mask {mask.shape} does not match image {image.shape[:2]}")
    out = image.copy()
    if not mask.any() or pixels <= 0:
        return out
    distance, (near_row, near_col) = ndimage.distance_transform_edt(~mask, return_indices=True)
    fill = (~mask) & (distance <= pixels)
    out[fill] = image[near_row[fill], near_col[fill]]
    return out
