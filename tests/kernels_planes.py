"""Flat test surfaces with hand-made atlases for the kernels technique (no xatlas run)."""

import numpy as np
from fixtures import plane

from sssbake.pipeline.core.surface import Surface, vertex_areas
from sssbake.pipeline.mesh.atlas import Atlas, AtlasPart

UP = (0.0, 0.0, 1.0)


def flat_surface(spacing: float, half: int) -> Surface:
    """A regular plane in z = 0 (mm units), one primitive, welded as is."""
    v, f, _ = plane(spacing, half)
    return Surface(v, f, np.tile(UP, (len(v), 1)), vertex_areas(v, f), (np.arange(len(v)),))


def plane_atlas(surface: Surface, size: int, margin: int = 6) -> Atlas:
    """One chart: the plane mapped linearly onto a `size`² atlas, `margin` texels from its edges."""
    x = surface.positions[:, :2]
    lo, span = x.min(axis=0), np.ptp(x, axis=0).max()
    uv = (margin + (x - lo) / span * (size - 2 * margin)) / size
    return Atlas((AtlasPart(np.arange(len(x)), surface.faces, uv),), size, size, 1, False, float("nan"))


def split_atlas(surface: Surface, size: int, gap: int = 12, margin: int = 6) -> Atlas:
    """Two charts cut along x = 0: the right half's vertices on the cut are duplicated and the
    half is shifted `gap` texels to the right in the atlas."""
    x = surface.positions[:, :2]
    lo, span = x.min(axis=0), np.ptp(x, axis=0).max()
    scale = (size - 2 * margin - gap) / span
    uv = margin + (x - lo) * scale
    right_face = surface.positions[surface.faces][:, :, 0].mean(axis=1) > 0
    cut = np.flatnonzero(np.abs(x[:, 0]) < 1e-9)
    copy = np.arange(len(x))
    copy[cut] = len(x) + np.arange(len(cut))
    faces = surface.faces.copy()
    faces[right_face] = copy[faces[right_face]]
    vmapping = np.r_[np.arange(len(x)), cut]
    uvs = uv[vmapping].copy()
    shifted = np.zeros(len(vmapping), dtype=bool)
    shifted[np.unique(faces[right_face])] = True
    uvs[shifted, 0] += gap
    return Atlas((AtlasPart(vmapping, faces, uvs / size),), size, size, 2, False, float("nan"))
