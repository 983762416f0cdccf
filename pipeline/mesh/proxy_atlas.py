"""Which UV layout a mesh's texel bakes use: its own, a simplified proxy's charts carried back, or
xatlas charting of the whole mesh.

xatlas charting of every scattering mesh took 50 of the 288 stage seconds of the auto batch of
../shared/assets, 20-37 % of the bunny's, Nefertiti's and the dragon's
(benchmarks/README.md#atlas-reuse); it serves the thickness texture, and the kernels technique.

1. **The input's UVs** (``reuse_input``): the first TEXCOORD set every part has that passes
   `uv_check.check_uvs` is used as it is: no new vertices, no new UV set. Kernels need a gutter
   around every chart for their border texels (`techniques.kernels.border`), which an artist's
   layout need not leave, so a bake with kernels asks for a charted atlas instead.
2. **A proxy's charts** (parts of at least `PROXY_MIN_FACES` triangles): the part is simplified to
   `PROXY_FACES` triangles (`simplify.simplify`, its vertices at their quadric-optimal points: kept
   at input vertices the proxy folded, p95 dihedral angle 169° on the hand, and xatlas cut it into
   450 charts against 27) and rid of its slivers (`_clean_proxy`), xatlas charts and packs the
   proxy, and the charts are carried back:
   every triangle of the part joins the chart of the proxy triangle nearest its centroid, and its
   corners take the UVs of their projections onto that proxy triangle (a vertex on a chart border
   gets one copy per chart, each the mean over its corners in that chart). The UVs of a chart stay
   within its proxy chart's footprint but for projections past its edge, less than a triangle of
   the full mesh, so the proxy's padding stays between charts. Folds where the surface has detail
   finer than the proxy are smoothed out (`_unfold`); the result must pass the same check, or the
   whole mesh is charted.
3. **xatlas on the whole mesh**, `atlas.compute_atlas`.

Every refusal is kept in ``Atlas.notes`` for the report.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.sparse import coo_matrix, diags
from scipy.sparse.csgraph import connected_components
from trimesh.triangles import angles, points_to_barycentric

from sssbake.pipeline.mesh.atlas import BLOCK, Atlas, AtlasError, AtlasPart, compute_atlas
from sssbake.pipeline.mesh.simplify import Simplified, SimplifyError, simplify
from sssbake.pipeline.mesh.surface_locate import locate_on_mesh
from sssbake.pipeline.mesh.uv_check import check_uvs

#: Triangles of a part's proxy (benchmarks/README.md#atlas-reuse: the 100k-triangle dragon's proxy
#: charts in under a second; coarser proxies fold more often where they are carried back).
PROXY_FACES = 5000
#: Parts with fewer triangles are charted as they are (below it xatlas takes about as long as
#: simplifying and carrying back: benchmarks/README.md#atlas-reuse).
PROXY_MIN_FACES = 12000
#: Smoothing steps that unfold the carried-back UVs (`_unfold`; on the dragon 0 left 0.090 % of the
#: texels doubly covered, 2 0.027 %, 5 0.010 %; benchmarks/README.md#atlas-reuse).
UNFOLD_STEPS = 5
#: Proxy edges shorter than this fraction of the proxy's median edge are collapsed (`_clean_proxy`).
#: Simplifying a midpoint-subdivided mesh (the 800k dragon, 1.6M triangles, to 5000) leaves a
#: quarter of its proxy's triangles with an edge under 0.05 of the median, most under 0.001
#: (vertices the simplifier stacked where the subdivision made the quadrics flat); the
#: unsubdivided 50k dragon's proxy has none under 0.05, 6 under 0.1, and is kept as it is
#: (benchmarks/README.md#proxy-slivers).
SLIVER_EDGE = 0.05
#: Proxy triangles with an angle under this (degrees) left after that are dropped: caps whose
#: third vertex lies on their longest edge (151 of the 800k dragon's proxy's 738 triangles with an
#: angle under 1°), no area to carry.
SLIVER_ANGLE = 1.0
#: A proxy that lost more than this fraction of its triangles to `_clean_proxy` is simplified
#: again with as many more asked for: the 800k dragon's 5000-triangle proxy kept 3748 and its
#: charts overlapped on 0.15 % of their texels (over `uv_check.OVERLAP_TOLERANCE`), 0.068 % with
#: 6670 asked (5388 kept); the 150k dragon's kept 4683 and passes, 0.029 %
#: (benchmarks/README.md#proxy-slivers).
SLIVER_LOSS = 0.1


def layout_atlas(
    parts: list[tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]],
    resolution: int,
    padding: int,
    *,
    reuse_input: bool = True,
    proxy_faces: int = PROXY_FACES,
    proxy_min_faces: int = PROXY_MIN_FACES,
) -> Atlas:
    """The atlas a mesh's texel bakes use (module docstring).

    Parameters
    ----------
    parts : list of (positions (n_i, 3) float64, faces (m_i, 3) int64, uv sets tuple of (n_i, 2))
        Per primitive its render vertices, triangles and input UV sets (TEXCOORD_0, 1, ...).
    resolution, padding : int
        As `atlas.compute_atlas`; input UVs are checked at ``resolution`` rounded up to `BLOCK`.
    reuse_input : bool
        Whether the input's UVs may serve (False where a technique needs gutters).
    proxy_faces, proxy_min_faces : int
        Proxy size and the part size from which a proxy is charted.

    Returns
    -------
    Atlas
        ``source`` says which layout; ``notes`` why the earlier ones were refused.
    """
    notes: list[str] = []
    if reuse_input:
        side = -(-resolution // BLOCK) * BLOCK
        sets = min(len(uvs) for _, _, uvs in parts)
        if not sets:
            notes.append("input UVs: none")
        for n in range(sets):
            check = check_uvs([(uvs[n], faces, positions) for positions, faces, uvs in parts], side, side)
            if check.ok:
                atlas_parts = tuple(AtlasPart(np.arange(len(positions)), np.asarray(faces, dtype=np.int64),
                                              np.asarray(uvs[n], dtype=np.float64)) for positions, faces, uvs in parts)
                return Atlas(atlas_parts, side, side, 0, False, float("nan"), f"TEXCOORD_{n}", tuple(notes))
            notes.append(f"input TEXCOORD_{n}: {check.reason}")
    geometry = [(np.asarray(p, dtype=np.float64), np.asarray(f, dtype=np.int64)) for p, f, _ in parts]
    if any(len(f) >= proxy_min_faces for _, f in geometry):
        try:
            atlas = _proxy_atlas(geometry, resolution, padding, proxy_faces, proxy_min_faces)
        except (SimplifyError, AtlasError) as e:  # the whole mesh may still chart
            notes.append(f"proxy charts: {e}; the whole mesh was charted")
        else:
            check = check_uvs([(part.uvs, part.faces, p[part.vmapping])
                               for part, (p, _) in zip(atlas.parts, geometry)],
                              atlas.width, atlas.height, min_coverage=0.0)
            if check.ok:
                return replace(atlas, notes=tuple(notes))
            notes.append(f"proxy charts: {check.reason}; the whole mesh was charted")
    return replace(compute_atlas(geometry, resolution, padding), notes=tuple(notes))


def _proxy_atlas(geometry: list[tuple[np.ndarray, np.ndarray]], resolution: int, padding: int, proxy_faces: int,
                 proxy_min_faces: int) -> Atlas:
    """One xatlas atlas of the parts, those of `proxy_min_faces` triangles or more charted through a
    proxy of `proxy_faces` triangles and carried back (others charted as they are)."""
    proxies = [_proxy(p, f, proxy_faces) if len(f) >= proxy_min_faces else None for p, f in geometry]
    charted = compute_atlas([s if s is not None else g for s, g in zip(proxies, geometry)], resolution, padding)
    parts = tuple(part if s is None else carry_back(p, f, *s, part)
                  for part, s, (p, f) in zip(charted.parts, proxies, geometry))
    return replace(charted, parts=parts, source="proxy")


def _proxy(positions: np.ndarray, faces: np.ndarray, proxy_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(positions (k, 3), faces (p, 3)): a proxy of about `proxy_faces` triangles without slivers
    (`_clean_proxy`; once more with more triangles asked where it lost over `SLIVER_LOSS`)."""
    proxy = _clean_proxy(simplify(positions, faces, target_count=proxy_faces, snap=False))
    if len(proxy[1]) < (1.0 - SLIVER_LOSS) * proxy_faces:
        asked = round(proxy_faces * proxy_faces / max(len(proxy[1]), 1))
        proxy = _clean_proxy(simplify(positions, faces, target_count=asked, snap=False))
    return proxy


def _clean_proxy(proxy: Simplified) -> tuple[np.ndarray, np.ndarray]:
    """A proxy without slivers: the ends of every edge shorter than `SLIVER_EDGE` of the median
    edge merged at their mean, then triangles left with two corners on one vertex or an angle
    under `SLIVER_ANGLE` dropped.

    A sliver has no barycentric frame of its own, so the full-mesh triangles nearest it land on
    its UV centroid or far outside it, and xatlas cuts charts at it: on the 800k dragon the
    carried-back charts overlapped on 0.56 % of their texels, 0.15 % with the slivers gone
    (benchmarks/README.md#proxy-slivers). A proxy without slivers is returned as it is.

    Parameters
    ----------
    proxy : Simplified
        ``positions`` (k, 3) float64 and ``faces`` (p, 3) int64.

    Returns
    -------
    positions : (k', 3) float64
    faces : (p', 3) int64
        Every vertex used by a face.
    """
    positions, faces = proxy.positions, proxy.faces
    edges = np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    length = np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1)
    short = edges[length < SLIVER_EDGE * np.median(length)]
    n = len(positions)
    _, group = connected_components(coo_matrix((np.ones(len(short)), (short[:, 0], short[:, 1])), shape=(n, n)),
                                    directed=False)
    size = np.bincount(group)
    merged = np.column_stack([np.bincount(group, weights=positions[:, d]) / size for d in range(3)])
    faces = group[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    with np.errstate(divide="ignore", invalid="ignore"):
        corner_angle = angles(merged[faces])
    faces = faces[np.nan_to_num(corner_angle, nan=0.0).min(axis=1) >= np.radians(SLIVER_ANGLE)]
    if not len(faces):
        raise SimplifyError("proxy: every triangle was a sliver")
    used = np.unique(faces)
    index = np.full(len(merged), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return merged[used], index[faces]


def carry_back(positions: np.ndarray, faces: np.ndarray, proxy_positions: np.ndarray, proxy_faces: np.ndarray,
               proxy_part: AtlasPart) -> AtlasPart:
    """The charts of a proxy's atlas carried back to the mesh it simplifies.

    Parameters
    ----------
    positions : (n, 3) float64
    faces : (m, 3) int64
        The full mesh.
    proxy_positions : (k, 3) float64
    proxy_faces : (p, 3) int64
        Its proxy, close to the same surface.
    proxy_part : AtlasPart
        The proxy's atlas part (``faces`` in the order of `proxy_faces`).

    Returns
    -------
    AtlasPart
        Over the full mesh: one atlas vertex per (vertex, chart) pair, triangles in input order.
    """
    # charts: the proxy's atlas triangles joined through shared atlas vertices
    corners = proxy_part.faces
    edges = coo_matrix((np.ones(2 * len(corners)), (corners[:, [0, 1]].ravel(), corners[:, [1, 2]].ravel())),
                       shape=(len(proxy_part.uvs),) * 2)
    _, component = connected_components(edges, directed=False)
    proxy_chart = component[corners[:, 0]]

    face_proxy, _ = locate_on_mesh(positions[faces].mean(axis=1), proxy_positions, proxy_faces)
    chart = proxy_chart[face_proxy]

    # one atlas vertex per (vertex, chart of a triangle using it)
    pair = faces.astype(np.int64) * (int(chart.max()) + 1) + chart[:, None]
    _, first, inverse = np.unique(pair.ravel(), return_index=True, return_inverse=True)
    vertex = faces.ravel()[first]
    # every corner projected onto its triangle's proxy triangle (its plane, not clamped into it: a
    # clamp folds the surface on both sides of a crest finer than the proxy onto one proxy edge),
    # a vertex's UV the mean over its corners in the chart (a nearest proxy triangle per vertex
    # took a second search, half the carry-back's time on the dragon, for as many folds:
    # benchmarks/README.md#atlas-reuse)
    corner_proxy = np.repeat(face_proxy, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        bary = points_to_barycentric(proxy_positions[proxy_faces[corner_proxy]], positions[faces.ravel()])
    # a proxy triangle without area (the simplifier can leave some) has no barycentric frame: its
    # corners go to its UV centroid, and the check below judges the result
    bary[~np.isfinite(bary).all(axis=1)] = 1.0 / 3.0
    corner_uv = np.einsum("sk,skd->sd", bary, proxy_part.uvs[corners[corner_proxy]])
    share = 1.0 / np.bincount(inverse, minlength=len(first))
    uvs = np.column_stack([np.bincount(inverse, weights=corner_uv[:, d], minlength=len(first)) * share
                           for d in range(2)])
    atlas_faces = inverse.reshape(-1, 3).astype(np.int64)
    # (a vertex projected past its chart's edge stays within the proxy's padding, but not always
    # within the texture: xatlas puts some charts at its border)
    uvs = np.clip(_unfold(uvs, atlas_faces, chart), 0.0, 1.0)
    return AtlasPart(vertex.astype(np.int64), atlas_faces, uvs)


def _unfold(uvs: np.ndarray, faces: np.ndarray, chart: np.ndarray) -> np.ndarray:
    """`uvs` with the vertices of UV triangles turned against their chart (folds where the surface
    has detail finer than the proxy) and their neighbours moved to their neighbours' mean, up to
    `UNFOLD_STEPS` times: Laplacian smoothing of the fold alone, which unfolds it."""
    n = len(uvs)
    rows = faces[:, [0, 1, 2, 1, 2, 0]].ravel()
    cols = faces[:, [1, 2, 0, 0, 1, 2]].ravel()
    adjacency = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0
    mean = diags(1.0 / np.maximum(np.asarray(adjacency.sum(axis=1)).ravel(), 1.0)) @ adjacency
    uvs = uvs.copy()
    for _ in range(UNFOLD_STEPS):
        e0, e1 = uvs[faces[:, 1]] - uvs[faces[:, 0]], uvs[faces[:, 2]] - uvs[faces[:, 0]]
        signed = e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0]
        orientation = np.sign(np.bincount(chart, weights=signed))
        folded = signed * orientation[chart] <= 0.0
        if not folded.any():
            break
        moved = np.zeros(n, dtype=bool)
        moved[faces[folded].ravel()] = True
        moved |= (adjacency @ moved.astype(np.float64)) > 0  # and their neighbours: room to unfold
        uvs[moved] = (mean @ uvs)[moved]
    return uvs
