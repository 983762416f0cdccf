"""Read the spectral technique's subsurface normals (Patro 2007) back from an exported .glb, per
mesh primitive: the ``_SSS_NORMAL`` vertex attribute (VEC3, normalized shorts), decoded as glTF
decodes it. ``verify`` and the round-trip tests use it.
"""

from __future__ import annotations

import os

import numpy as np
import pygltflib

from ..pipeline.spectral_layout import NORMAL_ATTRIBUTE
from .gltf import dequantize, read_accessor

#: The vertex attribute the bake writes the subsurface normals to.


class SpectralReadError(ValueError):
    """The file holds no subsurface normals, or holds them malformed."""


def read_spectral_glb(path: str | os.PathLike) -> dict[tuple[int, int], np.ndarray]:
    """``(mesh index, primitive index) -> normals (p, 3) float64`` over the primitive's vertices,
    for every primitive with a ``_SSS_NORMAL`` attribute.

    The decoded normals are as stored (snorm16 rounding, ~3e-5 per component), not renormalised:
    what a runtime reads unless it normalises them itself.
    """
    gltf = pygltflib.GLTF2.load(str(path))
    blob = gltf.binary_blob()
    out = {}
    for i, mesh in enumerate(gltf.meshes):
        for j, prim in enumerate(mesh.primitives):
            index = getattr(prim.attributes, NORMAL_ATTRIBUTE, None)
            if index is None:
                continue
            accessor = gltf.accessors[index]
            if accessor.type != "VEC3" or accessor.count != gltf.accessors[prim.attributes.POSITION].count:
                raise SpectralReadError(f"{path}: mesh {i} primitive {j}: {NORMAL_ATTRIBUTE} must be VEC3 with one "
                                        f"value per vertex, got {accessor.type} x {accessor.count}")
            out[(i, j)] = dequantize(read_accessor(gltf, index, blob), bool(accessor.normalized))
    if not out:
        raise SpectralReadError(f"{path}: no primitive holds {NORMAL_ATTRIBUTE} (bake with --techniques spectral)")
    return out
