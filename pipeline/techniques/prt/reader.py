"""Read the prt data of an exported .glb or .usdc back into `PrtData`, per mesh primitive.

The inverse of what `pipeline.prt_layout` lays out; ``verify`` and the round-trip tests use it.
"""

from __future__ import annotations

import os
from pathlib import Path

from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_primitives
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.layout import prt_from_layout


class PrtReadError(SssbakeError, ValueError):
    """The file holds no prt data, or holds it malformed."""


def read_prt_glb(path: str | os.PathLike) -> dict[tuple[int, int], PrtData]:
    """``(mesh index, primitive index) -> PrtData`` over the primitive's vertices, for every
    primitive of a mesh whose ``SSSBAKE_subsurface`` object has ``prt``.

    Raises
    ------
    StaleDataError
        The tables or attributes no longer match their references (`gltf_tables`).
    """
    data = load_sssbake_gltf(path, required=True)
    out = {(i, j): prt_from_layout(tables, per_vertex)
           for i, tables, primitives in technique_primitives(data, "prt", _attribute_names)
           for j, per_vertex in enumerate(primitives)}
    if not out:
        raise PrtReadError(f"{path}: no mesh holds prt data (bake with --techniques prt)")
    return out


def read_prt_usd(path: str | os.PathLike) -> dict[str, PrtData]:
    """Mesh prim path -> PrtData, for every UsdGeom.Mesh whose ``sss:extras`` has ``prt``.

    Raises
    ------
    StaleDataError
        A table or a primvar it names is missing or no longer matches (`exporters.usd.technique_data`).
    """
    from pxr import Usd

    from sssbake.exporters.usd import technique_data

    stage = Usd.Stage.Open(str(Path(path)))
    out = {}
    for prim in stage.Traverse():
        found = technique_data(prim, "prt")
        if found is not None:
            out[str(prim.GetPath())] = prt_from_layout(*found)
    if not out:
        raise PrtReadError(f"{path}: no mesh holds prt data (bake with --techniques prt)")
    return out


def _attribute_names(tables: dict) -> list[str]:
    """The per-vertex attributes the prt tables name (no weights attribute with 8-bit weights)."""
    names = tables["attributes"]
    return [names["ref"], *([names["weights"]] if "weights" in names else []), *names["dq"]]
