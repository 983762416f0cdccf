"""Read the lpv technique's grids (Børlum et al. 2011) back from an exported .glb or .usdc, per
mesh: the inverse of `pipeline.lpv_layout`, and what each grid was voxelised from
(`read_lpv_sources_glb`, `read_lpv_sources_usd`). ``verify`` and the round-trip tests use it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_tables
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.layout import LpvSource, lpv_grid_from_tables, lpv_source_from_tables


class LpvReadError(SssbakeError, ValueError):
    """The file holds no lpv data, or holds it malformed."""


def read_lpv_glb(path: str | os.PathLike) -> dict[tuple[int, int], tuple[LpvGrid, np.ndarray, np.ndarray]]:
    """``(mesh index, primitive index) -> (LpvGrid, matrices (6, 4, 4), render scales (S, 3))``
    for every primitive of a mesh whose ``SSSBAKE_subsurface`` object has ``lpv`` (one grid per mesh,
    in its frame at its ``scaleMm``: its primitives share it).

    Raises
    ------
    StaleDataError
        The tables no longer match their references (`gltf_tables`).
    """
    data = load_sssbake_gltf(path, required=True)
    out = {}
    for i, mesh in enumerate(data.gltf.meshes):
        tables = technique_tables(data, "meshes", i, "lpv")
        if tables is not None:
            grid = _grid(tables, float(data.extension(mesh)["scaleMm"]), f"{path}: mesh {i}")
            out.update({(i, j): grid for j in range(len(mesh.primitives))})
    if not out:
        raise LpvReadError(f"{path}: no mesh holds lpv data (bake with --techniques lpv)")
    return out


def read_lpv_usd(path: str | os.PathLike) -> dict[str, tuple[LpvGrid, np.ndarray, np.ndarray]]:
    """Mesh prim path -> (LpvGrid, matrices, render scales), for every UsdGeom.Mesh whose
    ``sss:extras`` has ``lpv``."""
    from pxr import Usd

    from sssbake.exporters.usd import technique_tables as usd_tables

    stage = Usd.Stage.Open(str(Path(path)))
    out = {str(prim.GetPath()): _grid(tables, float(prim.GetAttribute("sss:scaleMm").Get()), f"{path}: {prim.GetPath()}")
           for prim in stage.Traverse() if (tables := usd_tables(prim, "lpv")) is not None}
    if not out:
        raise LpvReadError(f"{path}: no mesh holds lpv data (bake with --techniques lpv)")
    return out


def read_lpv_sources_glb(path: str | os.PathLike) -> dict[tuple[int, int], LpvSource | None]:
    """``(mesh index, primitive index) -> LpvSource`` (`lpv_layout.lpv_source_from_tables`: the
    field and voxelisation the grid came from; None for files that do not record it, schema 1.7.x)
    for the same primitives as `read_lpv_glb`."""
    data = load_sssbake_gltf(path, required=True)
    out = {}
    for i, mesh in enumerate(data.gltf.meshes):
        tables = (data.extension(mesh) or {}).get("lpv")  # the JSON alone: no table is read
        if tables is not None:
            source = _source(tables, f"{path}: mesh {i}")
            out.update({(i, j): source for j in range(len(mesh.primitives))})
    if not out:
        raise LpvReadError(f"{path}: no mesh holds lpv data (bake with --techniques lpv)")
    return out


def read_lpv_sources_usd(path: str | os.PathLike) -> dict[str, LpvSource | None]:
    """Mesh prim path -> LpvSource (or None), for the same prims as `read_lpv_usd`."""
    from pxr import Usd

    from sssbake.exporters.usd import technique_tables as usd_tables

    stage = Usd.Stage.Open(str(Path(path)))
    out = {str(prim.GetPath()): _source(tables, f"{path}: {prim.GetPath()}")
           for prim in stage.Traverse() if (tables := usd_tables(prim, "lpv")) is not None}
    if not out:
        raise LpvReadError(f"{path}: no mesh holds lpv data (bake with --techniques lpv)")
    return out


def _source(tables: dict, where: str) -> LpvSource | None:
    try:
        return lpv_source_from_tables(tables)
    except ValueError as error:
        raise LpvReadError(f"{where}: {error}") from None


def _grid(tables: dict, mm_per_unit: float, where: str):
    try:
        return lpv_grid_from_tables(tables, mm_per_unit)
    except ValueError as error:
        raise LpvReadError(f"{where}: {error}") from None
