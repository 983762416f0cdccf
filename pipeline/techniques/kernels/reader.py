"""Read the kernels data of an exported .glb or .usdc back, per mesh primitive.

The inverse of what `pipeline.kernels_layout` lays out. A glTF mesh holds one atlas, so its
primitives share one `KernelsData`; USD writes the mesh's tables onto each of its Mesh prims, so
each prim gets its own (equal) copy.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_primitives
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.kernels.data import KernelsData
from sssbake.pipeline.techniques.kernels.layout import (
    kernels_data_from_tables,
    vertex_attribute_name,
    vertex_ids_from_layout,
)


class KernelsReadError(SssbakeError, ValueError):
    """The file holds no kernels data, or a primitive lacks its vertex attribute."""


def read_kernels_glb(path: str | os.PathLike) -> dict[tuple[int, int], tuple[KernelsData, np.ndarray]]:
    """``(mesh index, primitive index) -> (KernelsData, vertex_ids (p,) int64)`` for every primitive
    of a mesh whose ``SSSBAKE_subsurface`` object has ``kernels``.

    Raises
    ------
    StaleDataError
        The tables or attributes no longer match their references (`gltf_tables`).
    """
    out = {}
    for i, tables, primitives in technique_primitives(load_sssbake_gltf(path, required=True), "kernels",
                                                      lambda t: [vertex_attribute_name(t)]):
        data = kernels_data_from_tables(tables)  # one atlas per mesh: its primitives share it
        for j, per_vertex in enumerate(primitives):
            out[(i, j)] = data, vertex_ids_from_layout(tables, per_vertex)
    if not out:
        raise KernelsReadError(f"{path}: no mesh holds kernels data (bake with --techniques kernels)")
    return out


def read_kernels_usd(path: str | os.PathLike) -> dict[str, tuple[KernelsData, np.ndarray]]:
    """Mesh prim path -> (KernelsData, vertex_ids (p,) int64), for every UsdGeom.Mesh whose
    ``sss:extras`` has ``kernels``.

    Raises
    ------
    StaleDataError
        A table or the vertex primvar is missing or no longer matches (`exporters.usd.technique_data`).
    """
    from pxr import Usd

    from sssbake.exporters.usd import technique_data

    stage = Usd.Stage.Open(str(Path(path)))
    out = {}
    for prim in stage.Traverse():
        found = technique_data(prim, "kernels")
        if found is not None:
            tables, per_vertex = found
            out[str(prim.GetPath())] = kernels_data_from_tables(tables), vertex_ids_from_layout(tables, per_vertex)
    if not out:
        raise KernelsReadError(f"{path}: no mesh holds kernels data (bake with --techniques kernels)")
    return out
