"""Read the prt data of an exported .glb or .usdc back into `PrtData`, per mesh primitive.

The inverse of what `pipeline.prt_layout` lays out; ``verify`` and the round-trip tests use it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pygltflib

from sssbake.exporters.gltf import technique_primitives
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.layout import prt_from_layout

PRIMVAR_PREFIX = "primvars:sss:prt:"


class PrtReadError(SssbakeError, ValueError):
    """The file holds no prt data, or holds it malformed."""


def read_prt_glb(path: str | os.PathLike) -> dict[tuple[int, int], PrtData]:
    """``(mesh index, primitive index) -> PrtData`` over the primitive's vertices, for every
    primitive of a mesh whose ``extras.sssbake`` has ``prt``."""
    gltf = pygltflib.GLTF2.load(str(path))
    blob = gltf.binary_blob()
    out = {(i, j): prt_from_layout(tables, per_vertex)
           for i, tables, primitives in technique_primitives(gltf, "prt", _attribute_names, PrtReadError, path, blob)
           for j, per_vertex in enumerate(primitives)}
    if not out:
        raise PrtReadError(f"{path}: no mesh holds prt data (bake with --techniques prt)")
    return out


def read_prt_usd(path: str | os.PathLike) -> dict[str, PrtData]:
    """Mesh prim path -> PrtData, for every UsdGeom.Mesh whose ``sss:extras`` has ``prt``."""
    from pxr import Usd, UsdGeom

    from sssbake.exporters.usd import technique_tables

    stage = Usd.Stage.Open(str(Path(path)))
    out = {}
    for prim in stage.Traverse():
        resolved = technique_tables(prim, "prt")
        if resolved is None:
            continue
        api = UsdGeom.PrimvarsAPI(prim)
        per_vertex = {}
        for name in _attribute_names(resolved):
            key = name.removeprefix("_SSS_PRT_").lower()
            primvar = api.GetPrimvar("sss:prt:" + key)
            if not primvar:
                raise PrtReadError(f"{path}: {prim.GetPath()} lacks {PRIMVAR_PREFIX}{key}")
            per_vertex[name] = np.asarray(primvar.Get()).reshape(-1, primvar.GetElementSize())
        out[str(prim.GetPath())] = prt_from_layout(resolved, per_vertex)
    if not out:
        raise PrtReadError(f"{path}: no mesh holds prt data (bake with --techniques prt)")
    return out


def _attribute_names(tables: dict) -> list[str]:
    """The per-vertex attributes the prt tables name (no weights attribute with 8-bit weights)."""
    names = tables["attributes"]
    return [names["ref"], *([names["weights"]] if "weights" in names else []), *names["dq"]]
