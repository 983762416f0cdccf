"""The planner's pilot (``--budget-rmse``): the parameters of a planned technique chosen by measuring
them on a subsample of the mesh, so the bake spends the fewest bytes and seconds that meet the
error budget; `plan_check` then checks the choice on the full asset.

The candidates of a technique run from cheap to dear (`candidates`: its ``pilot_candidates``, e.g.
prt's byte budgets, screen's sample counts, lpv's grid resolutions), followed on a rigid mesh by
those of its ``pilot_fallback`` (screen's: prt, for light crossing a thin part). The pilot renders
each candidate's runtime (its ``pilot_item``) on the subsample (`PILOT_VERTICES`, `PILOT_SIZE`²,
verify's light and camera) against the offline reference on the same subsample and takes the
first whose image RMSE is within the budget (a technique that ``pilot_measures_all`` measures
every candidate, for the check's estimates; the others stop there). A technique that is its own
reference (``pilot_reference``: lpv's heterogeneous medium, measured against the same field at
twice the resolution) replaces the dipole's. When none meets it, the candidate with the least
RMSE is chosen, and the reason says the budget was not met.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.core.surface import Surface, vertex_areas
from sssbake.pipeline.mesh.simplify import simplify
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.render.image_metrics import rmse, shared_exposure
from sssbake.pipeline.render.renderer import DEFAULT_LIGHT
from sssbake.pipeline.techniques.registry import technique
from sssbake.pipeline.techniques.technique import Candidate

#: Vertices of the subsample the pilot measures on.
PILOT_VERTICES = 4000
#: Side of the pilot's images, pixels; the check on the full asset renders at the same size, so
#: their figures compare.
PILOT_SIZE = 160


@dataclass(frozen=True)
class Pilot:
    """What the pilot measured for one (mesh, material).

    Attributes
    ----------
    candidates : tuple of Candidate
        All of them, cheapest first (the check escalates through the ones after `chosen`).
    rows : tuple of dict
        One per measured candidate, in order: ``label``, ``technique``, ``rmse_image``,
        ``seconds`` (its bake on the subsample), ``holds_bytes`` (False where prt's simplification
        stopped above the reference points its budget allows: never chosen while another holds).
    chosen : int
        Index into `candidates`.
    met : bool
        Whether the chosen candidate met the budget in the pilot.
    vertices : int
        The subsample's vertices.
    reference : str
        ``"dipole"`` or the technique's ``self_reference_label`` (heterogeneous lpv).
    """

    candidates: tuple
    rows: tuple
    chosen: int
    met: bool
    vertices: int
    reference: str


def candidates(name: str, params: dict, options: BakeOptions, vertices: int, deforming: bool) -> list[Candidate]:
    """The configurations of technique `name` (with the planner's `params`) the pilot tries, cheapest
    first, for a mesh of `vertices` welded vertices (module docstring)."""
    hooks = technique(name)
    found = hooks.pilot_candidates(params, options, vertices, deforming)
    if not found:
        raise ValueError(f"pilot: no candidates for technique {name!r}")
    if hooks.pilot_fallback is not None and not deforming:  # the fallback's bake would not follow the pose
        found += technique(hooks.pilot_fallback).pilot_candidates({}, options, vertices, deforming)
    return found


def pilot_surface(surface: Surface, vertices: int = PILOT_VERTICES) -> Surface:
    """`surface` simplified to about `vertices` vertices (itself when not much larger), each kept
    vertex with its own normal."""
    if len(surface.positions) <= 1.5 * vertices:
        return surface
    # quadric-optimal positions: the closer surface (benchmarks/README.md#pilot-subsample)
    s = simplify(surface.positions, surface.faces, target_count=2 * vertices, snap=False)
    return Surface(positions=s.positions, faces=s.faces, normals=surface.normals[s.kept],
                   vertex_areas=vertex_areas(s.positions, s.faces), weld=(np.arange(len(s.positions)),))


def run_pilot(found: list[Candidate], surface: Surface, mm_per_unit: float, material: Material,
              options: BakeOptions, budget: float, vertices: int, world: np.ndarray | None = None,
              light=None) -> Pilot:
    """Measure `found` (`candidates`) in order on `surface`'s subsample and choose the first within
    `budget` (module docstring).

    Parameters
    ----------
    surface : Surface
        The mesh's welded surface (file units).
    vertices : int
        The full surface's welded vertices (prt's counts are the full asset's).
    world : (4, 4) float64, optional
        The mesh's first instance's world matrix (identity by default): the pilot sees the mesh
        as verify does, from its camera under its light, both in world space.
    light : (3,) float, optional
        World direction towards the light (`render.DEFAULT_LIGHT`, verify's, by default).
    """
    from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera

    if not found:
        raise ValueError("pilot: no candidate to measure")
    small = pilot_surface(surface, PILOT_VERTICES)
    world = np.eye(4) if world is None else np.asarray(world, dtype=np.float64)
    direction = np.asarray(DEFAULT_LIGHT if light is None else light, dtype=np.float64)
    direction /= np.linalg.norm(direction)
    local = np.linalg.solve(world[:3, :3], direction)  # the reference works in the mesh's frame
    local /= np.linalg.norm(local)
    renderer = Renderer((PILOT_SIZE, PILOT_SIZE))
    camera = fit_camera(small.positions @ world[:3, :3].T + world[:3, 3])
    lit = RenderLight(False, tuple(direction), 1.0)
    base = dict(positions=small.positions, normals=small.normals, faces=small.faces, model=world, eta=material.eta)
    dipole, label = None, "dipole"  # the dipole's image, coverage and exposure, rendered when first needed
    memos = {}  # per technique, what its pilot items keep from one candidate to the next
    try:
        rows, chosen, met = [], None, False
        for i, c in enumerate(found):
            hooks, merged = technique(c.technique), options.merged(c.params)
            memo = memos.setdefault(c.technique, {})
            t = time.perf_counter()
            item, holds_bytes = hooks.pilot_item(merged, small, mm_per_unit, material, vertices, memo)
            seconds = time.perf_counter() - t
            own = hooks.pilot_reference(item, small, merged, memo)
            if own is not None:
                reference, mask = renderer.render([{**base, **own}], camera, lit)
                exposure, label = shared_exposure(reference, mask), hooks.self_reference_label
            else:
                if dipole is None:
                    q = reference_scattering(small, mm_per_unit, material, Light("directional", tuple(local)))
                    image, mask = renderer.render([{**base, "q": q.T}], camera, lit)
                    dipole = image, shared_exposure(image, mask)
                reference, exposure = dipole
            error = rmse(renderer.render([{**base, **item}], camera, lit)[0], reference, exposure)
            rows.append({"label": c.label, "technique": c.technique, "rmse_image": error, "seconds": seconds,
                         "holds_bytes": holds_bytes})
            if error <= budget and holds_bytes and chosen is None:
                chosen, met = i, True
            if chosen is not None and not hooks.pilot_measures_all:
                break
    finally:
        renderer.release()
    if chosen is None:  # the least RMSE, among the candidates that held their bytes if any did
        held = [i for i, r in enumerate(rows) if r["holds_bytes"]] or range(len(rows))
        chosen = min(held, key=lambda i: rows[i]["rmse_image"])
    return Pilot(tuple(found), tuple(rows), chosen, met, len(small.positions), label)
