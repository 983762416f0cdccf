"""The lpv stage of a bake: one mesh voxelised into its material grid, with the propagation
matrices and the rendering's scale, laid out (with what it was voxelised from, `lpv_layout.lpv_source`),
with its report."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.baked import VertexAttribute
from sssbake.pipeline.techniques.lpv.calibrate import render_scales
from sssbake.pipeline.techniques.lpv.grid import LpvGridOptions, homogeneous, voxelise
from sssbake.pipeline.techniques.lpv.layout import lpv_bytes, lpv_grid_from_tables, lpv_source, lpv_tables
from sssbake.pipeline.techniques.lpv.marble_field import MarbleOptions, marble_field
from sssbake.pipeline.techniques.lpv.matrices import propagation_matrices
from sssbake.pipeline.techniques.lpv.options import FIELDS, LpvOptions
from sssbake.pipeline.techniques.technique import BakeTarget, TechniqueBake, same_tables

#: Above this diffusion decay per cell (σ_tr Δx) the bake warns and the planner refines the grid
#: (the error grows fast past it: benchmarks/README.md#lpv-cell-size).
LPV_COARSE = 2.0


def bake_lpv(surface: Surface, mm_per_unit: float, material: Material, grid_options: LpvGridOptions,
             field: str, marble: MarbleOptions, max_steps: int) -> TechniqueBake:
    """The lpv stage (module docstring).

    Parameters
    ----------
    surface : Surface
        The mesh's welded surface (open or folded ones too: `lpv_grid.voxelise`).
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
    scales = render_scales(grid, max_steps, material.profile, material.escape_gain)
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
    return TechniqueBake(None, tables, report)


class LpvStage:
    """lpv's bake hooks (`technique.Technique`): a grid per mesh, nothing per vertex."""

    def bake(self, target: BakeTarget, options: LpvOptions) -> TechniqueBake:
        baked = bake_lpv(target.surface, target.mm_per_unit, target.material, options.grid(), options.field,
                         options.marble(), options.max_steps)
        coarse = max(baked.report["decayPerCell"])
        if coarse <= LPV_COARSE:
            return baked
        # light then barely leaves its cell: the calibrated radiance amplifies the error
        need = int(np.ceil(options.resolution * coarse / LPV_COARSE))
        return replace(baked, warnings=(
            f"lpv cells of {baked.report['cellMm']:.3g} mm are wider than the material's diffusion length "
            f"(sigma_tr * cell = {coarse:.2g}); pass --lpv-resolution {need} or more",))

    def vertex_attributes(self, result: TechniqueBake, welded: np.ndarray) -> tuple[VertexAttribute, ...]:
        return ()

    def check_bake(self, result: TechniqueBake, target: BakeTarget, options: LpvOptions) -> None:
        tables = result.tables
        grid, matrices, scales = lpv_grid_from_tables(tables, target.mm_per_unit)  # checked: shapes, ranges
        if len(scales) != options.max_steps or tables.get("field") != options.field:
            raise ValueError("lpv: tables for other steps or another field than its options'")
        if result.data is not None or not same_tables(tables, lpv_tables(grid, matrices, scales, options.field,
                                                                         tables.get("source"))):
            raise ValueError("lpv: tables are not as its bake lays them out")

    def stage_options(self, options: LpvOptions) -> LpvOptions:
        # a homogeneous medium has no veins
        return options if options.field == "marble" else replace(options, vein_mm=LpvOptions().vein_mm)
