"""The lpv stage of a bake: one mesh voxelised into its material grid, with the propagation
matrices and the rendering's scale, laid out (with what it was voxelised from, `lpv_layout.lpv_source`),
with its report."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from .clean import Surface
from .lpv_calibrate import render_scales
from .lpv_grid import LpvGridOptions, homogeneous, voxelise
from .lpv_layout import lpv_bytes, lpv_source, lpv_tables
from .lpv_matrices import propagation_matrices
from .marble_field import MarbleOptions, marble_field
from .materials import Material

#: Where a grid's coefficients can come from.
FIELDS = ("homogeneous", "marble")
#: Above this diffusion decay per cell (σ_tr Δx) the bake warns and the planner refines the grid:
#: measured on a skin ball, image RMSE 0.05 at 1.8 (32³), 0.13 at 3.6 (16³), 0.35 at 4.8 (12³).
LPV_COARSE = 2.0


@dataclass(frozen=True, eq=False)
class BakedLpv:
    """What the lpv stage makes for one mesh: the `lpv_tables` and the report."""

    tables: dict
    report: dict


def bake_lpv(surface: Surface, mm_per_unit: float, material: Material, grid_options: LpvGridOptions,
             field: str, marble: MarbleOptions, max_steps: int) -> BakedLpv:
    """The lpv stage (module docstring).

    Parameters
    ----------
    surface : Surface
        The mesh's welded surface (closed).
    mm_per_unit : float
    material : Material
        The mesh's material: the whole medium (``"homogeneous"``) or the marble's body
        (``"marble"``: veins of `marble` through it).
    grid_options : LpvGridOptions
    field : str
        One of `FIELDS`.
    marble : MarbleOptions
        The veins (its ``base`` is replaced by `material`).
    max_steps : int
        Step counts the rendering's scale is tabulated for (1 .. max_steps).
    """
    if field not in FIELDS:
        raise ValueError(f"lpv: field must be one of {list(FIELDS)}, got {field!r}")
    seconds = {}
    t = time.perf_counter()
    veins = None if field == "homogeneous" else replace(marble, base=material)
    source = homogeneous(material) if veins is None else marble_field(mm_per_unit, veins)
    grid = voxelise(surface, mm_per_unit, source, material.eta, grid_options)
    seconds["voxelise"] = time.perf_counter() - t
    t = time.perf_counter()
    scales = render_scales(grid, max_steps)
    seconds["calibrate"] = time.perf_counter() - t
    # the field's parameters travel with the grid: a reader can rebuild it (verify's reference)
    tables = lpv_tables(grid, propagation_matrices(), scales, field,
                        lpv_source(field, mm_per_unit, grid_options, material, veins))
    medium = grid.occupancy > 0
    report = {
        "shape": tables["shape"],
        "cellMm": tables["cellMm"],
        "field": field,
        "cellsWithMedium": int(medium.sum()),
        # σ_tr Δx: the diffusion decay across one cell (above ~1 the grid is too coarse for the channel)
        "decayPerCell": (grid.sigma_t[medium] * (3.0 * (1.0 - grid.albedo[medium])) ** 0.5).mean(axis=0).astype(float)
                        .__mul__(grid.cell_mm).tolist(),
        "maxSteps": max_steps,
        "renderScaleAt16": scales[min(16, max_steps) - 1].tolist(),
        "seconds": seconds,
        "bytes": lpv_bytes(tables),
    }
    return BakedLpv(tables, report)
