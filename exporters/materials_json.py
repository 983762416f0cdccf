"""``<stem>.materials.json``: every translucent material's engine-native subsurface parameters.

One record per translucent material of the asset (`engine_materials.engine_materials`), keyed by
the material's name as exported, under the asset's one scale (`usd.mm_per_unit`, the same the
.usdc declares and its ``sss:openpbr:*`` attributes are written at)::

    {"schema": 1, "asset": <stem>, "scaleMm": <mm per file unit>,
     "materials": {<name>: {"measured": {...}, "unreal": {...}, "unityHdrp": {...}, "godot4": {...},
                            "openpbr": {...}, "khrMaterialsVolumeScatter": {...}}}}

`khr_volume_scatter` gives the ``khrMaterialsVolumeScatter`` records alone, by material index: what
the .glb carries with ``--khr-materials-volume-scatter`` (`gltf.glb_pieces`), the same numbers.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.usd import mm_per_unit
from sssbake.pipeline.core.engine_materials import engine_materials, khr_materials_volume_scatter
from sssbake.pipeline.mesh.baked import BakedAsset

SCHEMA = 1


def khr_volume_scatter(asset: BakedAsset) -> dict[int, dict]:
    """Scattering material index -> its ``khrMaterialsVolumeScatter`` record, as `materials_document`
    writes it (`engine_materials.khr_materials_volume_scatter` at `mm_per_unit`)."""
    scale = mm_per_unit(asset)
    return {m: khr_materials_volume_scatter(s.material, scale) for m, s in sorted(asset.scattering.items())}


def materials_document(asset: BakedAsset, stem: str) -> dict:
    """The document for `asset` written as `stem` (see the module)."""
    scale = mm_per_unit(asset)
    records = {}
    for m, scattering in sorted(asset.scattering.items()):
        name = asset.scene.materials[m].name or f"material{m}"
        if name in records:  # two source materials of one name: the index tells them apart
            name = f"{name}#{m}"
        fb = scattering.fallback
        # the thickness texture holds thickness / thickness_factor (file units)
        thickness_mm = fb.thickness_factor * scale if fb.thickness_texture is not None else None
        records[name] = engine_materials(scattering.material, scale, thickness_mm)
    return {"schema": SCHEMA, "asset": stem, "scaleMm": scale, "materials": records}


def write_materials_json(asset: BakedAsset, path: str | os.PathLike, stem: str) -> dict:
    """Write `materials_document` to `path` atomically; return ``{"path", "bytes", "materials"}``.

    Raises ValueError on a number that is not finite (``allow_nan=False``): the engines take none.
    """
    path = Path(path)
    text = json.dumps(materials_document(asset, stem), indent=1, allow_nan=False)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)
    return {"path": str(path), "bytes": path.stat().st_size, "materials": len(asset.scattering)}
