"""Read the spectral technique's subsurface normals (Patro 2007) back from an exported .glb, per
mesh primitive: the ``_SSS_NORMAL`` vertex attribute (VEC3 float32), as stored, or from an exported
.usdc: the ``primvars:sss:normal`` primvar of each mesh prim.
``verify`` and the round-trip tests use them.
"""

from __future__ import annotations

import os

import numpy as np

from sssbake.exporters.gltf_tables import load_sssbake_gltf
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.spectral.layout import NORMAL_ATTRIBUTE, NORMAL_KEY


class SpectralReadError(SssbakeError, ValueError):
    """The file holds no subsurface normals, or holds them malformed."""


def read_spectral_glb(path: str | os.PathLike) -> dict[tuple[int, int], np.ndarray]:
    """``(mesh index, primitive index) -> normals (p, 3) float64`` over the primitive's vertices,
    for every primitive with a ``_SSS_NORMAL`` attribute.

    The normals are as stored (float32 rounding), not renormalised:
    what a runtime reads unless it normalises them itself.

    Raises
    ------
    StaleDataError
        The attribute no longer matches the file's declaration (`gltf_tables`).
    """
    data = load_sssbake_gltf(path, required=True)
    out = {}
    for i, mesh in enumerate(data.gltf.meshes):
        for j, prim in enumerate(mesh.primitives):
            if getattr(prim.attributes, NORMAL_ATTRIBUTE, None) is None:
                continue
            normals = data.attribute(i, j, NORMAL_ATTRIBUTE)
            if normals.ndim != 2 or normals.shape[1] != 3:
                raise SpectralReadError(f"{path}: mesh {i} primitive {j}: {NORMAL_ATTRIBUTE} must be VEC3, got shape "
                                        f"{normals.shape}")
            out[(i, j)] = normals
    if not out:
        raise SpectralReadError(f"{path}: no primitive holds {NORMAL_ATTRIBUTE} (bake with --techniques spectral)")
    return out


def read_spectral_usd(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Mesh prim path -> normals (p, 3) float64 over the prim's points, for every UsdGeom.Mesh with
    the subsurface-normal primvar (normal3f[], float32 as written)."""
    from pxr import Usd, UsdGeom

    from sssbake.exporters.usd import check_schema, primvar_values

    name = NORMAL_KEY.removeprefix("sss:")
    stage = Usd.Stage.Open(str(path))  # held: a traversal outlives no stage
    check_schema(stage)
    out = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar("sss:" + name)
        if not primvar:
            continue
        normals = primvar_values(primvar)
        points = UsdGeom.Mesh(prim).GetPointsAttr().Get()
        if normals.shape != (len(points), 3):
            raise SpectralReadError(f"{path}: {prim.GetPath()}: primvars:sss:{name} must be one normal per point, got "
                                    f"shape {normals.shape}")
        out[str(prim.GetPath())] = normals
    if not out:
        raise SpectralReadError(f"{path}: no mesh holds primvars:sss:{name} (bake with --techniques spectral)")
    return out
