"""Read the spectral technique's subsurface normals (Patro 2007) back from an exported .glb, per
mesh primitive: the ``_SSS_NORMAL`` vertex attribute (VEC3, normalized shorts), decoded as glTF
decodes it, or from an exported .usdc: the ``primvars:sss:normal`` primvar of each mesh prim.
``verify`` and the round-trip tests use them.
"""

from __future__ import annotations

import os

import numpy as np
import pygltflib

from sssbake.exporters.gltf import dequantize, read_accessor
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.spectral.layout import NORMAL_ATTRIBUTE, NORMAL_KEY


class SpectralReadError(SssbakeError, ValueError):
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


def read_spectral_usd(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Mesh prim path -> normals (p, 3) float64 over the prim's points, for every UsdGeom.Mesh with
    the subsurface-normal primvar (float32 as written)."""
    from pxr import Usd, UsdGeom

    name = NORMAL_KEY.removeprefix("sss:")
    stage = Usd.Stage.Open(str(path))  # held: a traversal outlives no stage
    out = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("sss:" + name)
        if not primvar:
            continue
        normals = np.asarray(primvar.Get(), dtype=np.float64).reshape(-1, 3)
        points = UsdGeom.Mesh(prim).GetPointsAttr().Get()
        if normals.shape != (len(points), 3):
            raise SpectralReadError(f"{path}: {prim.GetPath()}: primvars:sss:{name} must be one normal per point, got "
                                    f"shape {normals.shape}")
        out[str(prim.GetPath())] = normals
    if not out:
        raise SpectralReadError(f"{path}: no mesh holds primvars:sss:{name} (bake with --techniques spectral)")
    return out
