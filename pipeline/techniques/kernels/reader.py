"""Read the kernels data of an exported .glb or .usdc back, per mesh primitive.

The inverse of what `pipeline.kernels_layout` lays out. A glTF mesh holds one atlas, so its
primitives share one `KernelsData`; USD writes the mesh's tables onto each of its Mesh prims, so
each prim gets its own (equal) copy.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pygltflib

from sssbake.exporters.gltf import technique_primitives
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.kernels.data import KernelsData
from sssbake.pipeline.techniques.kernels.layout import VERTEX_KEY, kernels_data_from_tables, vertex_ids_from_layout


class KernelsReadError(SssbakeError, ValueError):
    """The file holds no kernels data, or a primitive lacks its vertex attribute."""


def read_kernels_glb(path: str | os.PathLike) -> dict[tuple[int, int], tuple[KernelsData, np.ndarray]]:
    """``(mesh index, primitive index) -> (KernelsData, vertex_ids (p,) int64)`` for every primitive
    of a mesh whose ``extras.sssbake`` has ``kernels``."""
    gltf = pygltflib.GLTF2.load(str(path))
    blob = gltf.binary_blob()
    out = {}
    for i, tables, primitives in technique_primitives(gltf, "kernels", lambda t: [t["attributes"]["vertex"]],
                                                      KernelsReadError, path, blob):
        data = kernels_data_from_tables(tables)  # one atlas per mesh: its primitives share it
        for j, per_vertex in enumerate(primitives):
            out[(i, j)] = data, vertex_ids_from_layout(tables, per_vertex)
    if not out:
        raise KernelsReadError(f"{path}: no mesh holds kernels data (bake with --techniques kernels)")
    return out


def read_kernels_usd(path: str | os.PathLike) -> dict[str, tuple[KernelsData, np.ndarray]]:
    """Mesh prim path -> (KernelsData, vertex_ids (p,) int64), for every UsdGeom.Mesh whose
    ``sss:extras`` has ``kernels``."""
    from pxr import Usd, UsdGeom

    from sssbake.exporters.usd import technique_tables

    stage = Usd.Stage.Open(str(Path(path)))
    out = {}
    for prim in stage.Traverse():
        resolved = technique_tables(prim, "kernels")
        if resolved is None:
            continue
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar(VERTEX_KEY)
        if not primvar:
            raise KernelsReadError(f"{path}: {prim.GetPath()} lacks primvars:{VERTEX_KEY}")
        stored = np.asarray(primvar.Get()).reshape(-1, primvar.GetElementSize())
        ids = vertex_ids_from_layout(resolved, {resolved["attributes"]["vertex"]: stored})
        out[str(prim.GetPath())] = kernels_data_from_tables(resolved), ids
    if not out:
        raise KernelsReadError(f"{path}: no mesh holds kernels data (bake with --techniques kernels)")
    return out
