"""Whether a set of texture coordinates can carry a texel bake (the thickness texture).

A UV layout serves the bake when every texel it covers stands for one surface point and every part
of the surface gets texels at a useful density:

* finite and inside [0, 1] (glTF wraps or clamps outside: the texel a point samples would not be
  the texel baked for it);
* no overlap: texel centres covered by two triangles (a mirrored or stacked chart) would hold the
  thickness of one of them only. Counted by rasterising at the atlas size, once for the first
  triangle over every texel and once for any other triangle that holds the centre, but for its
  neighbours turning the same way (they meet it on an edge or a corner). ``OVERLAP_TOLERANCE``
  of the covered texels may be doubly covered: a fold smaller than a texel costs a texel or two;
* no degenerate triangles: surface with (almost) no UV area gets no texels of its own
  (``DEGENERATE_AREA`` of the surface may);
* density: the layout must use ``MIN_COVERAGE`` of the texture, and the 10th percentile of the
  surface's texel density (by area) must be ``MIN_UNIFORMITY`` of its median. On the assets of
  ../shared/assets xatlas' charts cover 0.41-0.50 of its atlas (the dragon 0.24), in atlases grown
  from 512 to 640-944 texels a side: about 0.8 × 512² texels of surface
  (benchmarks/README.md#atlas-reuse). An input layout covering 0.25 of a 512² texture gets
  sqrt(0.25 / 0.8) = 0.56 of xatlas' texels per mm, a texel 1.8 times as wide: 0.5 mm on a 15 cm
  object, under the millimetres over which thickness and the scattering it drives vary. A tenth
  of the surface at under a quarter of the median density would be four times blurrier than the
  rest: a layout that starves a region.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.surface import triangle_areas
from sssbake.pipeline.mesh.texels import rasterize_atlas

#: Fraction of covered texels that may be covered twice.
OVERLAP_TOLERANCE = 1e-3
#: Fraction of the surface area whose UV triangles may be (nearly) degenerate.
DEGENERATE_AREA = 1e-3
#: A UV triangle is degenerate below this fraction of the median texel density (linear).
DEGENERATE_DENSITY = 1e-2
#: Least fraction of the texture the layout must cover (module docstring).
MIN_COVERAGE = 0.25
#: Least ratio of the 10th-percentile to the median texel density, by surface area.
MIN_UNIFORMITY = 0.25


@dataclass(frozen=True)
class UvCheck:
    """The verdict on one UV layout.

    Attributes
    ----------
    ok : bool
    reason : str
        Why the layout was refused ('' when ok), naming the failed test and its figures.
    coverage : float
        Fraction of the texture covered by UV triangles (sum of UV areas).
    overlap : float
        Fraction of covered texels covered twice.
    uniformity : float
        10th-percentile / median texel density over the surface.
    """

    ok: bool
    reason: str
    coverage: float
    overlap: float
    uniformity: float


def check_uvs(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], width: int, height: int,
              min_coverage: float = MIN_COVERAGE) -> UvCheck:
    """Test a UV layout shared by several parts against the module's criteria.

    Parameters
    ----------
    parts : list of (uvs (n_i, 2) float64, faces (m_i, 3) int64, positions (n_i, 3) float64)
        Per part its vertices' UVs (glTF convention) and positions, and its triangles.
    width, height : int
        Texture size in texels the layout is rasterised at.
    min_coverage : float
        Least covered fraction of the texture (`MIN_COVERAGE`; 0 for xatlas' own packing, whose
        atlas size is made for it).

    Returns
    -------
    UvCheck
    """
    nan = float("nan")
    uvs = [np.asarray(u, dtype=np.float64) for u, _, _ in parts]
    if not all(np.isfinite(u).all() for u in uvs):
        return UvCheck(False, "UVs contain NaN or Inf", nan, nan, nan)
    lo = min(float(u.min()) for u in uvs if u.size)
    hi = max(float(u.max()) for u in uvs if u.size)
    if lo < 0.0 or hi > 1.0:
        return UvCheck(False, f"UVs outside [0, 1] (range {lo:.3g} .. {hi:.3g}: tiled or offset)", nan, nan, nan)
    uv_area = np.concatenate([_uv_areas(u[f]) for u, (_, f, _) in zip(uvs, parts)])
    xyz_area = np.concatenate([triangle_areas(np.asarray(p, dtype=np.float64), f) for _, f, p in parts])
    coverage = float(uv_area.sum())
    # linear texel density (texels per unit length) of every triangle, weighted by surface area
    tiny = np.finfo(float).tiny
    density = np.sqrt(uv_area * width * height / np.maximum(xyz_area, tiny))
    order = np.argsort(density)
    cumulative = np.cumsum(xyz_area[order]) / max(xyz_area.sum(), tiny)
    p10, median = (float(density[order][min(np.searchsorted(cumulative, q), len(order) - 1)]) for q in (0.1, 0.5))
    uniformity = p10 / median if median > 0 else 0.0
    degenerate = float(xyz_area[density < DEGENERATE_DENSITY * median].sum() / max(xyz_area.sum(), tiny))
    if degenerate > DEGENERATE_AREA:
        return UvCheck(False, f"{degenerate:.2%} of the surface has degenerate UV triangles "
                              f"(at most {DEGENERATE_AREA:.1%})", coverage, nan, uniformity)
    if coverage * (1.0 - OVERLAP_TOLERANCE) > 1.0:  # overlapping for sure: no need to rasterise
        return UvCheck(False, f"UV triangles overlap: their areas add up to {coverage:.3g} times the texture",
                       coverage, nan, uniformity)
    overlap = _overlap(parts, uvs, width, height)
    if overlap > OVERLAP_TOLERANCE:
        return UvCheck(False, f"UV triangles overlap on {overlap:.2%} of the covered texels "
                              f"(at most {OVERLAP_TOLERANCE:.1%})", coverage, overlap, uniformity)
    if coverage < min_coverage:
        return UvCheck(False, f"UVs cover {coverage:.1%} of the texture (at least {min_coverage:.0%})",
                       coverage, overlap, uniformity)
    if uniformity < MIN_UNIFORMITY:
        return UvCheck(False, f"a tenth of the surface has under {uniformity:.2f} of the median texel density "
                              f"(at least {MIN_UNIFORMITY:.2f})", coverage, overlap, uniformity)
    return UvCheck(True, "", coverage, overlap, uniformity)


def _uv_areas(corners: np.ndarray) -> np.ndarray:
    """(m,) unsigned areas of UV triangles (m, 3, 2)."""
    e0, e1 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    return 0.5 * np.abs(e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0])


def _overlap(parts: list, uvs: list[np.ndarray], width: int, height: int) -> float:
    """Fraction of covered texels whose centre also lies in a second triangle: the rasteriser gives
    each texel its first triangle, then is run again with that triangle refused there, and its
    neighbours turning the same way (sharing a corner with it, they meet it only on an edge or a
    corner, where a centre can lie in both; a neighbour turned over it is a fold)."""
    geometry = [(u, np.asarray(f, dtype=np.int64), np.asarray(p, dtype=np.float64), np.asarray(p, dtype=np.float64))
                for u, (_, f, p) in zip(uvs, parts)]
    first = rasterize_atlas(geometry, width, height)
    if not len(first.rows):
        return 0.0
    offsets = np.cumsum([0] + [len(f) for _, f, _, _ in geometry])
    vertex_offsets = np.cumsum([0] + [len(u) for u, _, _, _ in geometry])
    corners = np.concatenate([f + o for (_, f, _, _), o in zip(geometry, vertex_offsets)])
    uv = np.concatenate([u for u, _, _, _ in geometry])[corners]
    e0, e1 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    turn = np.sign(e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0])
    owner = np.full(width * height, -1, dtype=np.int64)
    owner[first.rows * width + first.cols] = offsets[first.part] + first.face

    def accept(pixels: np.ndarray, triangles: np.ndarray) -> np.ndarray:
        own = owner[pixels]
        shared = (corners[triangles][:, :, None] == corners[own][:, None, :]).any(axis=(1, 2))
        return (own >= 0) & (own != triangles) & ~(shared & (turn[triangles] == turn[own]))

    second = rasterize_atlas(geometry, width, height, accept=accept)
    return len(second.rows) / len(first.rows)
