"""Read the prt data of an exported .glb or .usdc back into `PrtData`, per mesh primitive.

The inverse of what `pipeline.prt_layout` lays out; ``verify`` and the round-trip tests use it.
"""

from __future__ import annotations

import os
from pathlib import Path

from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_primitives
from sssbake.pipeline.core.errors import SssbakeError, StaleDataError
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.layout import prt_attribute_names, prt_from_layout


class PrtReadError(SssbakeError, ValueError):
    """The file holds no prt data, or holds it malformed."""


def read_prt_glb(path: str | os.PathLike) -> dict[tuple[int, int], PrtData]:
    """``(mesh index, primitive index) -> PrtData`` over the primitive's vertices, for every
    primitive of a mesh whose ``SSSBAKE_subsurface`` object has ``prt``.

    Raises
    ------
    StaleDataError
        The tables or attributes no longer match their references (`gltf_tables`), or a prt block is
        malformed: a field missing, of the wrong JSON type or out of range (named in the message, with
        the mesh).
    """
    data = load_sssbake_gltf(path, required=True)
    out = {(i, j): _prt(tables, per_vertex, path, f"mesh {i}")
           for i, tables, primitives in technique_primitives(data, "prt", lambda tables: _names(tables, path))
           for j, per_vertex in enumerate(primitives)}
    if not out:
        raise PrtReadError(f"{path}: no mesh holds prt data (bake with --techniques prt)")
    return out


def read_prt_usd(path: str | os.PathLike) -> dict[str, PrtData]:
    """Mesh prim path -> PrtData, for every UsdGeom.Mesh whose ``sss:extras`` has ``prt``.

    Raises
    ------
    StaleDataError
        A table or a primvar it names is missing or no longer matches (`exporters.usd.technique_data`),
        or a prt block is malformed (as `read_prt_glb`).
    """
    from pxr import Usd

    from sssbake.exporters.usd import technique_data

    stage = Usd.Stage.Open(str(Path(path)))
    out = {}
    for prim in stage.Traverse():
        found = technique_data(prim, "prt")
        if found is not None:
            out[str(prim.GetPath())] = _prt(*found, path, str(prim.GetPath()))
    if not out:
        raise PrtReadError(f"{path}: no mesh holds prt data (bake with --techniques prt)")
    return out


def _names(tables: dict, path: str | os.PathLike) -> list[str]:
    """`prt_attribute_names`, its ValueError a `StaleDataError` of `path`."""
    try:
        return prt_attribute_names(tables)
    except ValueError as error:
        raise StaleDataError(path, str(error)) from None


def _prt(tables: dict, per_vertex: dict, path: str | os.PathLike, where: str) -> PrtData:
    """`prt_from_layout`, its ValueError a `StaleDataError` of `path` saying `where` (the mesh) first."""
    try:
        return prt_from_layout(tables, per_vertex)
    except ValueError as error:
        raise StaleDataError(path, f"{where}: {error}") from None
