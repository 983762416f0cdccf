"""lpv: verify and the runtime (`technique.Technique`'s verify hooks).

The dipole knows only a homogeneous medium: a grid voxelised from a heterogeneous field
(``field`` "marble") is compared with its own self-convergence reference instead
(`lpv_reference`): the same field, as the file records it, re-voxelised from the welded surface at
twice the resolution, calibrated the same way and drawn by the same lpv runtime with
proportionally more steps ("lpv 2x").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sssbake.pipeline.core.errors import VerifyError
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.techniques.lpv.calibrate import render_scales
from sssbake.pipeline.techniques.lpv.data import LpvGrid
from sssbake.pipeline.techniques.lpv.grid import voxelise
from sssbake.pipeline.techniques.lpv.layout import LpvSource, lpv_bytes, lpv_tables
from sssbake.pipeline.techniques.lpv.matrices import propagation_matrices
from sssbake.pipeline.techniques.lpv.propagate import LPV_DEFAULTS, MAX_STEPS
from sssbake.pipeline.techniques.lpv.reader import read_lpv_glb, read_lpv_sources_glb, read_lpv_usd
from sssbake.pipeline.techniques.lpv.runtime import LPV_DRAW
from sssbake.pipeline.techniques.technique import VerifyShot, VerifyUnit

#: verify's ``reference`` where lpv grids from a heterogeneous field were compared with `lpv_reference`.
LPV_SELF_REFERENCE = "lpv 2x (heterogeneous medium: no closed-form reference)"
#: Finest grid `lpv_reference` builds, cells along the longest side: 2x a 128³ bake, 16.8 M cells
#: (8x its cells and 16x its propagation work); finer bakes cannot be checked against 2x.
LPV_REFERENCE_MAX_RESOLUTION = 256


class LpvVerify:
    """A mesh's grid (all its primitives), drawn after the lpv passes with verify's ``lpv_steps``
    (the runtime's `LPV_DEFAULTS` where None); compared with the dipole, or with `lpv_reference` for
    a heterogeneous field, with where light leaks (`lpv_leaks`)."""

    draw = LPV_DRAW
    self_reference_label = LPV_SELF_REFERENCE

    def read(self, path) -> dict:
        return read_lpv_glb(path)

    def read_usd(self, path) -> dict:
        return read_lpv_usd(path)

    def verify_items(self, unit: VerifyUnit, data: dict, runtime: dict) -> tuple[dict, dict]:
        grid, matrices, scales = data[(unit.mesh, unit.primitives[0])]
        item = {**unit.base, "lpv": grid, "lpv_matrices": matrices, "lpv_scales": scales,
                "lpv_steps": _steps(runtime)}
        return item, item

    def reference_item(self, path, unit: VerifyUnit, data: dict, runtime: dict, memo: dict
                       ) -> tuple[dict, tuple[int, int]] | None:
        """`lpv_reference`'s item for a grid from a heterogeneous field (one per mesh, whatever
        the instances' transforms) and its (resolution, steps); None for a homogeneous one."""
        if "sources" not in memo:
            memo["sources"] = read_lpv_sources_glb(path)
        source = memo["sources"].get((unit.mesh, unit.primitives[0]))
        field = str((unit.extras.get("lpv") or {}).get("field", "homogeneous"))
        if source is None and field != "homogeneous":
            raise VerifyError(f"verify: {path}: mesh {unit.mesh}'s lpv grid comes from a {field!r} field but the file "
                             "does not record its parameters (schema before 1.8.0): bake it again")
        if source is None or str(source.field) == "homogeneous":
            return None
        finer_grids = memo.setdefault("finer", {})  # mesh index -> `lpv_reference`
        if unit.mesh not in finer_grids:
            grid = data[(unit.mesh, unit.primitives[0])][0]
            finer_grids[unit.mesh] = lpv_reference(unit.surface, source, grid, _steps(runtime))
        finer, scales, steps, resolution = finer_grids[unit.mesh]
        return ({**unit.base, "lpv": finer, "lpv_matrices": propagation_matrices(), "lpv_scales": scales,
                 "lpv_steps": steps}, (resolution, steps))

    def verify_figures(self, units: list[VerifyUnit], items: list[dict], shot: VerifyShot
                       ) -> tuple[np.ndarray, list, dict]:
        return shot.image, [], lpv_leaks(items, shot)


def lpv_reference(surface: Surface, source: LpvSource, grid: LpvGrid, steps: int
                  ) -> tuple[LpvGrid, np.ndarray, int, int]:
    """The self-convergence reference of an lpv grid voxelised from a heterogeneous field.

    The dipole has no answer for a veined medium, so the reference is the same technique one
    refinement further on: the field the file records (`lpv_layout.LpvSource`) re-voxelised from
    `surface` (the welded surface verify draws, in the mesh's frame) with the same padding and
    supersampling at twice the file's resolution (at most `LPV_REFERENCE_MAX_RESOLUTION`), its
    rendering's scale calibrated the same way (`lpv_calibrate.render_scales`), and as many more
    propagation steps as the cells are smaller (light moves one cell per step, so the reference's
    light travels as far in mm per frame as the file's). The image difference then measures how far
    the file's grid and step count are from converged, as `lpv_tradeoff` measures a veined medium
    against its finest configuration, not the distance to the truth.

    Parameters
    ----------
    surface : Surface
        Closed, file units.
    source : LpvSource
        What the file's grid was voxelised from.
    grid : LpvGrid
        The file's grid (its cell and index of refraction).
    steps : int
        The runtime's propagation steps for the file's grid.

    Returns
    -------
    finer : LpvGrid
    scales : (S, 3) float64
        The finer grid's rendering scale for 1 .. S steps.
    finer_steps : int
        S: the reference's propagation steps.
    resolution : int
        The finer grid's cells along the longest side.
    """
    resolution = int(source.grid.resolution)
    finer = min(2 * resolution, LPV_REFERENCE_MAX_RESOLUTION)
    if finer <= resolution:
        raise VerifyError(f"verify: an lpv grid of {resolution} cells has no finer self-convergence reference within "
                         f"{LPV_REFERENCE_MAX_RESOLUTION} cells")
    options = replace(source.grid, resolution=finer)
    voxels = voxelise(surface, source.mm_per_unit, source.material_field(), grid.eta, options)
    finer_steps = min(max(1, int(round(steps * grid.cell_mm / voxels.cell_mm))), MAX_STEPS)
    scales = render_scales(voxels, finer_steps, source.material.profile, source.material.escape_gain)
    return voxels, scales, finer_steps, finer


def lpv_leaks(items: list[dict], shot: VerifyShot) -> dict:
    """Where the lpv technique's image has light the reference does not, and how coarse its grids
    are; `items` are the lpv render items, `shot` as `screen_verify.screen_misses`'.

    Returns
    -------
    dict
        ``excess_share``: Σ max(image - reference, 0) / Σ reference over the object's pixels;
        ``excess_share_unlit``: its part at pixels the light does not reach directly (light that
        crossed the grid, through the object or across a gap the grid's cells bridge);
        ``thin_cells``: the share of the first grid's cells with medium that are mostly outside the
        surface (occupancy < 0.5: where cells bridge thin gaps); ``lpv_steps``; ``bytes_per_mesh``
        (the first grid's float32 tables).
    """
    mask = shot.mask
    lit = shot.lit.any(axis=-1) if shot.lit.ndim == 3 else shot.lit
    excess = np.maximum(shot.image - shot.reference, 0.0).sum(axis=-1)
    total = max(float(shot.reference[mask].sum()), 1e-300)
    grid = items[0]["lpv"]
    medium = grid.occupancy > 0
    return {"excess_share": float(excess[mask].sum() / total),
            "excess_share_unlit": float(excess[mask & ~lit].sum() / total),
            "thin_cells": float(np.mean(grid.occupancy[medium] < 0.5)) if medium.any() else 0.0,
            "lpv_steps": int(items[0]["lpv_steps"]),
            "bytes_per_mesh": lpv_bytes(lpv_tables(grid, items[0]["lpv_matrices"], items[0]["lpv_scales"],
                                                   "homogeneous"))["total"]}


def _steps(runtime: dict) -> int:
    """verify's propagation steps per frame."""
    return LPV_DEFAULTS.steps if runtime["lpv_steps"] is None else int(runtime["lpv_steps"])
