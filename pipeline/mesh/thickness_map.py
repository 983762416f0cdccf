"""The thickness texture: one inward ray bake per covered atlas texel, gutters dilated.

A texel casts along its interpolated shading normal (`thickness` module docstring, Hard edges);
its triangle's longest edge sets the depth of the winding-number probes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas
from sssbake.pipeline.mesh.texels import dilate, rasterize_atlas
from sssbake.pipeline.mesh.thickness import bake_thickness


@dataclass(frozen=True, eq=False)
class ThicknessMap:
    """Thickness per atlas texel.

    Attributes
    ----------
    image : (H, W) float64
        Thickness in mesh units; gutter texels within the atlas padding copy their nearest
        covered texel, texels farther out are 0.
    mask : (H, W) bool
        Texels covered by a triangle.
    escaped : int
        Covered texels most of whose rays did not end on the surface: they ended where the
        winding number fell to 1/2, or found no inside (`thickness.bake_thickness`).
    """

    image: np.ndarray
    mask: np.ndarray
    escaped: int


def bake_thickness_map(
    atlas: Atlas,
    vertices: list[tuple[np.ndarray, np.ndarray]],
    surface: Surface,
    cap: float,
    rays: int,
    padding: int,
) -> ThicknessMap:
    """Bake thickness at every texel of `atlas`.

    Parameters
    ----------
    atlas : Atlas
        Atlas over the mesh's primitives.
    vertices : list of (positions (n_i, 3), normals (n_i, 3))
        Each primitive's render vertices, in the order of ``atlas.parts``.
    surface : Surface
        The mesh's welded surface: the rays' targets.
    cap, rays :
        As `thickness.bake_thickness` (mesh units, rays per texel).
    padding : int
        Texels of gutter to fill around each chart.
    """
    parts = [
        (part.uvs, part.faces, pos[part.vmapping], nrm[part.vmapping])
        for part, (pos, nrm) in zip(atlas.parts, vertices)
    ]
    texels = rasterize_atlas(parts, atlas.width, atlas.height)
    # the texel's triangle sets the depth of the winding-number probes
    corners = np.empty((len(texels.face), 3, 3))
    for i, (_, faces, positions, _) in enumerate(parts):
        mine = texels.part == i
        corners[mine] = positions[faces[texels.face[mine]]]
    result = bake_thickness(
        surface.positions, surface.faces, origins=texels.positions, directions=-texels.normals,
        probe=np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2).max(axis=1), cap=cap, rays=rays,
    )
    image = np.zeros((atlas.height, atlas.width))
    image[texels.rows, texels.cols] = result.thickness
    mask = texels.mask
    return ThicknessMap(dilate(image, mask, padding), mask, int((~result.hit).sum()))
