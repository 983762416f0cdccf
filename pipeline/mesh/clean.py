"""Cleaning stage: drop degenerate and unused data, fill missing normals, and build the welded
surface every scattering computation runs on.

Render vertices (split at UV and normal seams) are kept for export; the welded `Surface` joins
coincident positions so adjacency, areas and normals see one connected surface.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, triangle_areas, unit_rows, vertex_areas
from sssbake.pipeline.mesh.scene import Mesh, Primitive, Scene
from sssbake.pipeline.mesh.tangents import vertex_tangents

# Positions closer than this fraction of the bounding-box diagonal are the same point.
WELD_TOLERANCE = 1e-7
# Triangles with area below this fraction of diagonal² carry no surface.
DEGENERATE_AREA = 1e-14
# A mesh whose vertices but for a few (`CORE_SHARE`) lie within this fraction of its bounding-box
# diagonal is refused: its few outliers (corrupt positions) would set the weld and area tolerances
# above, and at 1e-5 these would already merge points 1 % of the body apart.
OUTLIER_EXTENT = 1e-5
CORE_SHARE = 0.99
# Largest coordinate magnitude, file units: the outputs' positions are float32 (glTF POSITION, USD
# point3f), and below it products of up to three coordinate differences (areas, normals, volumes)
# stay finite in float64 with 190 decades to spare.
MAX_COORDINATE = float(np.finfo(np.float32).max)


@dataclass(frozen=True, eq=False)
class CleanScene:
    """Output of the cleaning stage.

    Attributes
    ----------
    scene : Scene
        Same structure as the input; each primitive without degenerate faces or unused vertices,
        with unit normals, and with tangents where its material has a normal texture.
    surfaces : tuple of Surface
        One per mesh, same order as ``scene.meshes``.
    warnings : tuple of str
    """

    scene: Scene
    surfaces: tuple[Surface, ...]
    warnings: tuple[str, ...]


def weld_positions(positions: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Join positions that agree to `tolerance` (absolute, file units).

    Returns
    -------
    welded : (w, 3) float64
        The first position of each group.
    index : (n,) int64
        Welded index of each input position.
    """
    if tolerance > 0:
        keys = np.round(positions / tolerance).astype(np.int64)
    else:
        keys = positions
    _, first, index = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return positions[first], index.reshape(-1).astype(np.int64)


def _clean_primitive(prim: Primitive, tol: float, min_area: float) -> tuple[Primitive, int, int]:
    """Drop degenerate and repeated faces, the vertices nothing references, and unusable normals or
    tangents; also returns how many degenerate and how many repeated faces went."""
    _, welded_index = weld_positions(prim.positions, tol)
    f = prim.faces
    wf = welded_index[f]
    distinct = (wf[:, 0] != wf[:, 1]) & (wf[:, 1] != wf[:, 2]) & (wf[:, 0] != wf[:, 2])
    keep = distinct & (triangle_areas(prim.positions, f) > min_area)
    dropped = int((~keep).sum())
    f, wf = f[keep], wf[keep]
    # A face on the same welded corners, in the same turning order, as an earlier one adds its area
    # twice to every sum and stalls xatlas (400k copies of one triangle ran for hours); the
    # opposite order is a back face, kept.
    turned = np.take_along_axis(wf, (np.argmin(wf, axis=1)[:, None] + np.arange(3)) % 3, axis=1)
    first = np.sort(np.unique(turned, axis=0, return_index=True)[1])
    repeated = len(f) - len(first)
    f = f[first]
    used = np.unique(f)
    remap = np.full(len(prim.positions), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    faces = remap[f]
    positions = prim.positions[used]
    normals = prim.normals[used] if prim.normals is not None else None
    if normals is not None:
        # the largest component, not the length, which overflows for a finite 1e300
        bad = ~np.all(np.isfinite(normals), axis=1) | (np.abs(normals).max(axis=1, initial=0.0) < 1e-12)
        normals = None if bad.any() else unit_rows(normals)
    tangents = prim.tangents[used] if prim.tangents is not None else None
    if tangents is not None:
        bad = ~np.all(np.isfinite(tangents), axis=1) | (np.abs(tangents[:, :3]).max(axis=1, initial=0.0) < 1e-12)
        tangents = None if bad.any() else tangents
    cleaned = replace(
        prim,
        positions=positions,
        faces=faces,
        normals=normals,
        uvs=tuple(uv[used] for uv in prim.uvs),
        colors=prim.colors[used] if prim.colors is not None else None,
        tangents=tangents,
    )
    return cleaned, dropped, repeated


def weld_surface(prims: list[Primitive], tol: float) -> Surface:
    """The welded surface of `prims` (positions within `tol` joined), with normals and areas."""
    offsets = np.cumsum([0] + [len(p.positions) for p in prims])
    allpos = np.concatenate([p.positions for p in prims])
    allfaces = np.concatenate([p.faces + o for p, o in zip(prims, offsets)])
    welded, index = weld_positions(allpos, tol)
    faces = index[allfaces]
    return Surface(
        positions=welded,
        faces=faces,
        normals=area_weighted_normals(welded, faces),
        vertex_areas=vertex_areas(welded, faces),
        weld=tuple(index[offsets[i] : offsets[i + 1]] for i in range(len(prims))),
    )


def _encloses_negative_volume(surf: Surface) -> bool:
    """True when the surface's winding clearly points its normals inward.

    The signed volume of a closed surface is positive for outward winding; scans with small
    holes keep the sign. Open shells enclose little: they are left alone unless the signed
    volume is over 1% of the bounding box's.
    """
    p = surf.positions[surf.faces] - surf.positions.mean(axis=0)
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    return volume < -0.01 * float(np.prod(np.ptp(surf.positions, axis=0)))


def _flip_winding(prim: Primitive, inward_normals: np.ndarray) -> Primitive:
    """Reverse a primitive's triangles; authored normals that agreed with the inward winding flip too."""
    normals = prim.normals
    if normals is not None and np.einsum("ij,ij->", normals, inward_normals) > 0:
        normals = -normals
    return replace(prim, faces=prim.faces[:, ::-1].copy(), normals=normals)


def _refuse_outliers(source, name: str, positions: np.ndarray, diagonal: float) -> None:
    """Raise an AssetError when a few of `positions` (n, 3) lie so far out that the rest fill
    less than `OUTLIER_EXTENT` of the bounding-box `diagonal` (see `OUTLIER_EXTENT`)."""
    if diagonal == 0:
        return
    distance = np.linalg.norm(positions - np.median(positions, axis=0), axis=1)
    core = float(np.quantile(distance, CORE_SHARE))
    if core >= OUTLIER_EXTENT * diagonal:
        return
    far = distance > np.sqrt(max(core, 1e-300) * distance.max())  # between the core and the farthest
    raise AssetError(source, f"mesh {name!r}: {int(far.sum())} of {len(positions)} vertices lie far outside the "
                             f"rest (up to {distance.max():.3g} from their median, {CORE_SHARE:.0%} of them within "
                             f"{core:.3g}; they fill {core / diagonal:.2g} of the bounding box's diagonal): "
                             "corrupt positions? fix or remove those vertices")


def clean_scene(scene: Scene) -> CleanScene:
    """Clean every mesh of `scene` and build its welded surface.

    Raises
    ------
    AssetError
        When a coordinate exceeds `MAX_COORDINATE`, or no triangle with area survives (the asset
        has no surface to scatter on).
    """
    warnings: list[str] = []
    meshes: list[Mesh] = []
    surfaces: list[Surface] = []
    kept: dict[int, int] = {}
    for mi, mesh in enumerate(scene.meshes):
        allpos = np.concatenate([p.positions for p in mesh.primitives]) if mesh.primitives else np.zeros((0, 3))
        largest = float(np.abs(allpos).max()) if len(allpos) else 0.0
        if largest > MAX_COORDINATE:
            raise AssetError(scene.source, f"mesh {mesh.name!r}: coordinates reach {largest:.3g}, too large to "
                                           f"compute with (the limit is {MAX_COORDINATE:.3g}, float32's largest, "
                                           f"which the outputs store positions in); rescale the asset")
        diag = float(np.linalg.norm(np.ptp(allpos, axis=0))) if len(allpos) else 0.0
        _refuse_outliers(scene.source, mesh.name, allpos, diag)
        tol, min_area = WELD_TOLERANCE * diag, DEGENERATE_AREA * diag * diag
        prims = []
        for prim in mesh.primitives:
            cleaned, dropped, repeated = _clean_primitive(prim, tol, min_area)
            if dropped:
                warnings.append(f"mesh {mesh.name!r}: dropped {dropped} degenerate triangles")
            if repeated:
                warnings.append(f"mesh {mesh.name!r}: dropped {repeated} repeated triangles (the same corners as "
                                "another triangle's)")
            if len(cleaned.faces):
                prims.append(cleaned)
        if not prims:
            warnings.append(f"mesh {mesh.name!r}: no triangle with area; mesh left out")
            continue
        surf = weld_surface(prims, tol)
        if _encloses_negative_volume(surf):
            prims = [_flip_winding(p, surf.normals[w]) for p, w in zip(prims, surf.weld)]
            surf = weld_surface(prims, tol)
            warnings.append(f"mesh {mesh.name!r}: triangles were wound inward (negative enclosed volume); flipped")
        prims = [
            p if p.normals is not None else replace(p, normals=surf.normals[w]) for p, w in zip(prims, surf.weld)
        ]
        for pi, p in enumerate(prims):
            normal_texture = scene.materials[p.material].normal_texture if p.material is not None else None
            if normal_texture is None or p.tangents is not None:
                continue
            if normal_texture.uv_set < len(p.uvs):
                prims[pi] = replace(p, tangents=vertex_tangents(p.positions, p.faces, p.normals,
                                                                p.uvs[normal_texture.uv_set]))
            else:
                warnings.append(f"mesh {mesh.name!r} primitive {pi}: the normal texture uses "
                                f"TEXCOORD_{normal_texture.uv_set}, which the primitive lacks; no tangents")
        kept[mi] = len(meshes)
        meshes.append(Mesh(mesh.name, tuple(prims), mesh.deforming))
        surfaces.append(surf)
    if not meshes:
        raise AssetError(scene.source, "no triangle with non-zero area")
    nodes = tuple(replace(n, mesh=kept.get(n.mesh)) if n.mesh is not None else n for n in scene.nodes)
    return CleanScene(replace(scene, meshes=tuple(meshes), nodes=nodes), tuple(surfaces), tuple(warnings))
