"""Millimetres per file unit: the file's (or the user's) unit and each mesh's instance scale."""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.errors import AssetError
from sssbake.pipeline.core.ranges import SCALE_MM
from sssbake.pipeline.mesh.scene import Scene


def resolve_scale_mm(scene: Scene, scale_mm: float | None) -> tuple[float, str]:
    """Millimetres per file unit and where that number came from; refuses to guess.

    `scale_mm` is the user's (``--scale-mm``, ``scale_mm`` in the config), None when not given.
    """
    if scale_mm is not None:
        return float(scale_mm), "given"
    if scene.meters_per_unit is not None:
        declared = 1000.0 * scene.meters_per_unit
        if declared not in SCALE_MM:  # as a given scale_mm would be refused
            raise AssetError(scene.source, f"the file declares {declared:g} mm per unit, outside {SCALE_MM.text()}; "
                                           "pass --scale-mm (millimetres per file unit) or set scale_mm in the config")
        return declared, "declared by the file"
    raise AssetError(
        scene.source,
        "no scale: this format carries no unit; pass --scale-mm (millimetres per file unit) or set scale_mm in the config",
    )


def instance_scale(scene: Scene, mesh_index: int, warnings: list[str]) -> float:
    """Uniform world scale of the nodes instancing a mesh (1 when it is not instanced); instances at
    different scales add a warning to `warnings`."""
    worlds = scene.mesh_instances().get(mesh_index, [])
    scales = [abs(float(np.linalg.det(w[:3, :3]))) ** (1.0 / 3.0) for w in worlds]
    if not scales:
        return 1.0
    if max(scales) > min(scales) * (1 + 1e-6):
        warnings.append(
            f"mesh {scene.meshes[mesh_index].name!r} is instanced at scales {min(scales):.4g}..{max(scales):.4g}; "
            "baked with the first instance's scale"
        )
    return scales[0]
