"""lpv: the planner's pilot (`technique.Technique`'s pilot hooks).

Candidates: grid resolutions (`LPV_RESOLUTIONS`) from the planner's on. A heterogeneous medium
has no closed-form reference: each grid is measured against verify's reference for it, the same
field at twice the resolution (`lpv_verify.lpv_reference`).
"""

from __future__ import annotations

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.techniques.lpv.layout import lpv_grid_from_tables, lpv_source_from_tables
from sssbake.pipeline.techniques.lpv.propagate import LPV_DEFAULTS
from sssbake.pipeline.techniques.lpv.stage import bake_lpv
from sssbake.pipeline.techniques.lpv.verify import lpv_reference
from sssbake.pipeline.techniques.technique import Candidate

LPV_RESOLUTIONS = (16, 24, 32, 48, 64, 96, 128)


class LpvPilot:
    """Grid resolutions (module docstring); grids are dear, so the pilot stops at the first within
    the budget."""

    pilot_measures_all = False

    def pilot_candidates(self, params: dict, options, vertices: int, deforming: bool) -> list[Candidate]:
        start = params.get("lpv_resolution", options.technique_options("lpv").resolution)
        steps = [start] + [r for r in LPV_RESOLUTIONS if r > start]
        return [Candidate("lpv", {**params, "lpv_resolution": r}, f"lpv, grid {r}") for r in steps]

    def pilot_item(self, options, surface: Surface, mm_per_unit: float, material: Material, vertices: int,
                   memo: dict) -> tuple[dict, bool]:
        """The baked grid, drawn with the runtime's default steps; `memo` keeps its source for
        `pilot_reference`."""
        lpv = options.technique_options("lpv")
        baked = bake_lpv(surface, mm_per_unit, material, lpv.grid(), lpv.field, lpv.marble(), lpv.max_steps)
        grid, matrices, scales = lpv_grid_from_tables(baked.tables, mm_per_unit)
        memo["source"] = lpv_source_from_tables(baked.tables)
        return {"lpv": grid, "lpv_matrices": matrices, "lpv_scales": scales, "lpv_steps": LPV_DEFAULTS.steps}, True

    def pilot_reference(self, item: dict, surface: Surface, options, memo: dict) -> dict | None:
        """A heterogeneous medium's reference for the `item` made last, as verify draws it
        (`lpv_verify.lpv_reference`); None for a homogeneous one (the dipole)."""
        if options.technique_options("lpv").field == "homogeneous":
            return None
        grid, scales, steps, _ = lpv_reference(surface, memo["source"], item["lpv"], item["lpv_steps"])
        return {"lpv": grid, "lpv_matrices": item["lpv_matrices"], "lpv_scales": scales, "lpv_steps": steps}
