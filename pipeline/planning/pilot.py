"""The planner's pilot: every planned technique measured on a subsample of the mesh against the
offline reference and against the fallback's baseline, best-fit Lambert; under an error budget
(``--budget-rmse``) also its parameters chosen, so the bake spends the fewest bytes and seconds
that meet the budget; `plan_check` then checks the choice on the full asset.

The candidates of a technique run from cheap to dear (`candidates`: its ``pilot_candidates``, e.g.
prt's byte budgets, screen's sample counts, lpv's grid resolutions), followed on a rigid mesh by
those of its ``pilot_fallback`` (screen's: prt, for light crossing a thin part). The pilot renders
each candidate's runtime (its ``pilot_item``) on the subsample (`PILOT_VERTICES`, `PILOT_SIZE`²,
verify's light and camera) against the offline reference on the same subsample and takes the
first whose image RMSE is within the budget (a technique that ``pilot_measures_all`` measures
every candidate, for the check's estimates; the others stop there). A technique that is its own
reference (``pilot_reference``: lpv's heterogeneous medium, measured against the same field at
twice the resolution) replaces the profile's. When none meets it, the candidate with the least
RMSE is chosen, and the reason says the budget was not met.

Every candidate is also measured against best-fit Lambert (`verify.best_fit_lambert`: Lambert
shading with the per-channel scale that best fits the same reference, what verify reports as
``rmse_object_lambert``), both as object RMSE (over the pixels either covers, verify's
``rmse_object``). Only a candidate that `beats_lambert` by ``lambert_margin`` and holds its bytes is
eligible; when none is, the least RMSE is chosen all the same and the planner ships the fallback
alone. Without a budget the pilot measures every candidate given (the planned or requested
configurations) and chooses the first eligible.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.core.surface import Surface, vertex_areas
from sssbake.pipeline.core.visibility import direction_visibility
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
        ``rmse_object`` and ``lambert_rmse_object`` (best-fit Lambert's against the same
        reference), ``beats_lambert`` (by the options' ``lambert_margin``), ``seconds`` (its bake on
        the subsample), ``holds_bytes`` (False where prt's simplification stopped above the
        reference points its budget allows: never chosen while another holds).
    chosen : int
        Index into `candidates`: eligible (``beats_lambert`` and ``holds_bytes``) whenever one is.
    met : bool
        Whether the chosen candidate met the budget in the pilot (any eligible one without a budget).
    vertices : int
        The subsample's vertices.
    reference : str
        The material's profile model (``"montecarlo"``, ``"dipole"``) or the technique's
        ``self_reference_label`` (heterogeneous lpv).
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


def beats_lambert(rmse_object: float, lambert_rmse_object: float, margin: float) -> bool:
    """Whether a technique's object RMSE is under (1 - `margin`) x best-fit Lambert's: with a
    `margin` of 0, whether it is better than Lambert at all."""
    return rmse_object < (1.0 - margin) * lambert_rmse_object


def run_pilot(found: list[Candidate], surface: Surface, mm_per_unit: float, material: Material,
              options: BakeOptions, budget: float | None, vertices: int, world: np.ndarray | None = None,
              light=None) -> Pilot:
    """Measure `found` (`candidates`) in order on `surface`'s subsample and choose the first
    eligible one within `budget` (module docstring).

    Parameters
    ----------
    surface : Surface
        The mesh's welded surface (file units).
    budget : float or None
        Image RMSE; None: measure every candidate, choose the first eligible.
    vertices : int
        The full surface's welded vertices (prt's counts are the full asset's).
    world : (4, 4) float64, optional
        The mesh's first instance's world matrix (identity by default): the pilot sees the mesh
        as verify does, from its camera under its light, both in world space.
    light : (3,) float, optional
        World direction towards the light (`render.DEFAULT_LIGHT`, verify's, by default).
    """
    from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
    from sssbake.pipeline.verify.verify import best_fit_lambert, lambert_q

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
    visible = direction_visibility(small.positions, small.faces, small.normals, local[None])[:, 0]
    lambert = [{**base, "q": lambert_q(small.normals, local[None], visible)}]  # verify's, in the mesh's frame

    def compared(reference: np.ndarray, mask: np.ndarray) -> tuple:
        """`reference` (H, W, 3), its coverage `mask` (H, W), its exposure and best-fit Lambert's object RMSE."""
        exposure = shared_exposure(reference, mask)
        return reference, mask, exposure, best_fit_lambert(renderer, lambert, camera, lit, reference, mask, exposure)[2]

    # `compared` for the diffusion profile's image, rendered when first needed; labelled by its model
    profiled, label = None, material.profile
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
                reference, ref_mask, exposure, baseline = compared(*renderer.render([{**base, **own}], camera, lit))
                label = hooks.self_reference_label
            else:
                if profiled is None:
                    # clustered (far sources through clusters, float64): 0.02-0.11 % of q from the
                    # exact sum on the shared assets' subsamples, 4-16x cheaper
                    # (benchmarks/README.md#pilot-reference), against RMSEs of a few percent
                    q = reference_scattering(small, mm_per_unit, material, Light("directional", tuple(local)),
                                             clustered=True)
                    profiled = compared(*renderer.render([{**base, "q": q.T}], camera, lit))
                reference, ref_mask, exposure, baseline = profiled
            image, mask = renderer.render([{**base, **item}], camera, lit)
            error, error_object = rmse(image, reference, exposure), rmse(image, reference, exposure, ref_mask | mask)
            beats = beats_lambert(error_object, baseline, options.lambert_margin)
            rows.append({"label": c.label, "technique": c.technique, "rmse_image": error, "rmse_object": error_object,
                         "lambert_rmse_object": baseline, "beats_lambert": beats, "seconds": seconds,
                         "holds_bytes": holds_bytes})
            if (budget is None or error <= budget) and holds_bytes and beats and chosen is None:
                chosen, met = i, True
            if chosen is not None and budget is not None and not hooks.pilot_measures_all:
                break
    finally:
        renderer.release()
    if chosen is None:  # the least RMSE, among the eligible candidates, else those that held their bytes, if any
        eligible = ([i for i, r in enumerate(rows) if r["holds_bytes"] and r["beats_lambert"]]
                    or [i for i, r in enumerate(rows) if r["holds_bytes"]] or range(len(rows)))
        chosen = min(eligible, key=lambda i: rows[i]["rmse_image"])
    return Pilot(tuple(found), tuple(rows), chosen, met, len(small.positions), label)
