"""Render items shared by verify and the tradeoff sweeps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sssbake.pipeline.core.surface import area_weighted_normals
from sssbake.pipeline.mesh.scene import Primitive

#: Colour of the plain shader that frame times are compared with (its cost does not depend on it).
PLAIN_ALBEDO = (0.8, 0.8, 0.8)


def merged_primitive(prims: list) -> Primitive:
    """One primitive of all of `prims` (faces re-indexed), with normals where they lacked them."""
    normals = [p.normals if p.normals is not None else area_weighted_normals(p.positions, p.faces) for p in prims]
    offsets = np.cumsum([0] + [len(p.positions) for p in prims])
    uv_sets = min(len(p.uvs) for p in prims)
    return replace(prims[0], positions=np.concatenate([p.positions for p in prims]),
                   normals=np.concatenate(normals),
                   faces=np.concatenate([p.faces + o for p, o in zip(prims, offsets)]),
                   uvs=tuple(np.concatenate([p.uvs[len(p.uvs) - uv_sets + t] for p in prims]) for t in range(uv_sets)),
                   tangents=None, colors=None)
