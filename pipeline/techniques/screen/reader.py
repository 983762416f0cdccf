"""Read the screen technique's per-material sample tables (Mertens et al. 2003) back from an
exported .glb or .usdc: the inverse of `pipeline.screen_layout`. ``verify`` and the round-trip
tests use it.
"""

from __future__ import annotations

import os
from pathlib import Path

from sssbake.exporters.gltf_tables import load_sssbake_gltf, technique_tables
from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.techniques.screen.data import ScreenSamples
from sssbake.pipeline.techniques.screen.layout import screen_samples_from_tables


class ScreenReadError(SssbakeError, ValueError):
    """The file holds no screen tables, or holds them malformed."""


def read_screen_glb(path: str | os.PathLike) -> dict[tuple[int, int], ScreenSamples]:
    """``(mesh index, primitive index) -> ScreenSamples`` for every primitive whose material's
    ``SSSBAKE_subsurface`` object has ``screen`` (primitives of one material share one).

    Raises
    ------
    StaleDataError
        The tables no longer match their references (`gltf_tables`).
    """
    data = load_sssbake_gltf(path, required=True)
    gltf = data.gltf
    per_material = {}
    for m in range(len(gltf.materials)):
        tables = technique_tables(data, "materials", m, "screen")
        if tables is not None:
            per_material[m] = _samples(tables, f"{path}: material {m}")
    out = {(i, j): per_material[prim.material] for i, mesh in enumerate(gltf.meshes)
           for j, prim in enumerate(mesh.primitives) if prim.material in per_material}
    if not out:
        raise ScreenReadError(f"{path}: no primitive's material holds screen tables (bake with --techniques screen)")
    return out


def read_screen_usd(path: str | os.PathLike) -> dict[str, ScreenSamples]:
    """Material prim path -> ScreenSamples, for every UsdShade.Material whose ``sss:extras`` has
    ``screen``."""
    from pxr import Usd

    from sssbake.exporters.usd import technique_tables as usd_tables

    stage = Usd.Stage.Open(str(Path(path)))
    out = {str(prim.GetPath()): _samples(tables, f"{path}: {prim.GetPath()}")
           for prim in stage.Traverse() if (tables := usd_tables(prim, "screen")) is not None}
    if not out:
        raise ScreenReadError(f"{path}: no material holds screen tables (bake with --techniques screen)")
    return out


def _samples(tables: dict, where: str) -> ScreenSamples:
    try:
        return screen_samples_from_tables(tables)
    except ValueError as error:
        raise ScreenReadError(f"{where}: {error}") from None
