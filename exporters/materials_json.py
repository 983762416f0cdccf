"""``<stem>.materials.json``: every translucent material's engine-native subsurface parameters.

One record per translucent material of the asset (`engine_materials.engine_materials`), keyed by
the material's name as exported, under the asset's one scale (`usd.meters_per_unit`, the same the
.usdc declares and its ``sss:openpbr:*`` attributes are written at)::

    {"schema": 1, "asset": <stem>, "scaleMm": <mm per file unit>,
     "materials": {<name>: {"measured": {...}, "unreal": {...}, "unityHdrp": {...}, "godot4": {...},
                            "openpbr": {...}, "khrMaterialsVolumeScatter": {...}}}}
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.usd import meters_per_unit
from sssbake.pipeline.core.engine_materials import engine_materials
from sssbake.pipeline.mesh.baked import BakedAsset

SCHEMA = 1


def materials_document(asset: BakedAsset, stem: str) -> dict:
    """The document for `asset` written as `stem` (see the module)."""
    mm_per_unit = meters_per_unit(asset) * 1000.0
    records = {}
    for m, scattering in sorted(asset.scattering.items()):
        name = asset.scene.materials[m].name or f"material{m}"
        if name in records:  # two source materials of one name: the index tells them apart
            name = f"{name}#{m}"
        fb = scattering.fallback
        # the thickness texture holds thickness / thickness_factor (file units)
        thickness_mm = fb.thickness_factor * mm_per_unit if fb.thickness_texture is not None else None
        records[name] = engine_materials(scattering.material, mm_per_unit, thickness_mm)
    return {"schema": SCHEMA, "asset": stem, "scaleMm": mm_per_unit, "materials": records}


def write_materials_json(asset: BakedAsset, path: str | os.PathLike, stem: str) -> dict:
    """Write `materials_document` to `path` atomically; return ``{"path", "bytes", "materials"}``.

    Raises ValueError on a number that is not finite (``allow_nan=False``): the engines take none.
    """
    path = Path(path)
    text = json.dumps(materials_document(asset, stem), indent=1, allow_nan=False)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)
    return {"path": str(path), "bytes": path.stat().st_size, "materials": len(asset.scattering)}
