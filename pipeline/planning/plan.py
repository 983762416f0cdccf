"""``sssbake plan``: which technique each object and material of an asset needs, from what the scene
measures, each decision with a one-line reason (models only what a scene requires).

Per translucent (mesh, material), in order, the first rule that applies:

1. **nearly opaque**: half of the widest channel's R_d lies within a radius under the atlas texel
   footprint (diagonal / atlas resolution): scattering would not show; the standard fallback only
   (its base colour is R_d);
2. **heterogeneous** medium (``lpv_field`` other than homogeneous): lpv, the only technique with
   a per-cell medium; the grid resolution is the smallest whose cells hold σ_tr Δx <= `LPV_COARSE`
   in every channel (16 .. `LPV_MAX_RESOLUTION`);
3. **deforming** (glTF skin or morph targets, USD skeleton or blend shapes): no per-vertex bake;
   screen, which needs nothing per vertex;
4. **thin or small** relative to the diffusion length 1/σ_tr of the most translucent channel (median
   thickness under `THIN` diffusion lengths, or a diagonal under `SMALL`): light crosses the
   object, a global technique: prt (with ``max_bytes_per_vertex`` as its byte budget; screen when
   prt's tables cannot fit it);
5. otherwise thick, local scattering: screen (no per-vertex bytes).

Opaque materials (by assignment) get nothing. With an error budget (``budget_rmse``) the
technique's parameters come from a pilot on a subsample (`plan_pilot`, `piloted`), which may also
turn screen into prt; otherwise parameters not set by a rule keep the bake's defaults.

Never worse than the fallback: the pilot measures every planned technique (without a budget, its
planned configuration alone: `planned_candidate`) against best-fit Lambert on its subsample, and
the plan ships it only when its object RMSE is under (1 - ``lambert_margin``) x Lambert's;
otherwise the standard fallback alone, the reason giving both figures (`lambert_verdict`).
Techniques the user names (``--techniques T``) are baked as asked, measured the same way where
they have a pilot (`requested_checks`). `worse_than_lambert` and `lambert_line` mark and count
what a bake shipped worse than Lambert, for the batch summary and the HTML report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.profile import profile_for, radius_holding
from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.scale import instance_scale, resolve_scale_mm
from sssbake.pipeline.mesh.thickness import bake_thickness
from sssbake.pipeline.options import BakeOptions
from sssbake.pipeline.planning.assign import assign_materials
from sssbake.pipeline.planning.pilot import beats_lambert, candidates, run_pilot
from sssbake.pipeline.techniques.lpv.stage import LPV_COARSE
from sssbake.pipeline.techniques.prt.compress import budget_reference_count
from sssbake.pipeline.techniques.registry import technique
from sssbake.pipeline.techniques.technique import Candidate

#: Below this many diffusion lengths of median thickness, light crosses the object.
THIN = 4.0
#: Below this many diffusion lengths of bounding-box diagonal, the object is small.
SMALL = 20.0
#: Largest lpv grid the planner chooses (cells along the longest side).
LPV_MAX_RESOLUTION = 128
#: What each technique the rules choose is known to miss against physics (Mitsuba 3 volpath,
#: `benchmarks/bench_fidelity.py`, figures in docs/fidelity.md), said with the choice: the pilot
#: checks a technique against our own profile, which cannot show these.
PHYSICS_LIMITS = {
    "prt": "against physics prt beats best-fit Lambert on every bundled sample front- and back-lit but "
           "the 2 mm skin1 slab back-lit; front-lit, objects tens of diffusion lengths across can trail it "
           "(the marble hand: 0.051 against 0.041) (docs/fidelity.md)",
    "screen": "against physics screen misses light through parts the camera cannot see: back-lit it loses "
              "to best-fit Lambert (docs/fidelity.md)",
    "lpv": "against physics lpv is measured homogeneous only, and back-lit loses to best-fit Lambert there "
           "(docs/fidelity.md)",
}
#: Parts thinner than this many reduced mean free paths 1/σ'_t are crossed in a few scatterings:
#: how much gets through depends on the directions of light and view, which no diffusion profile
#: models (the 2 mm skin1 slab is 1.5-3 free paths thick: every technique loses to best-fit
#: Lambert there, docs/fidelity.md). The plan says so with any technique it chooses.
FEW_FREE_PATHS = 3.0


@dataclass(frozen=True)
class PlanEntry:
    """The plan of one translucent (or opaque) material of one mesh.

    Attributes
    ----------
    asset : str
    mesh : str
    material : str
        The source material's name.
    techniques : tuple of str
        Empty for none (the standard fallback only, or opaque).
    params : dict
        Bake options the plan sets (e.g. ``lpv_resolution``).
    reasons : tuple of str
        One line per decision.
    measures : dict
        What the rules read: ``diagonal_mm``, ``median_thickness_mm`` (area-weighted), ``diffusion_mm`` (per
        channel, 1/σ_tr), ``median_radius_mm`` (the widest channel's), ``texel_mm``, ``free_path_mm``
        (the longest channel's 1/σ'_t).
    pilot : dict
        With a budget (`piloted`): ``budget``, ``vertices`` (the subsample's), ``reference``,
        ``candidates`` (``label``, ``technique``, ``params``), ``rows`` (`plan_pilot.Pilot`),
        ``chosen`` (the pilot's pick), ``met``, ``pick`` (the candidate baked).
    lambert_check : dict
        The pilot's verdict against best-fit Lambert (`lambert_record`); empty when nothing was
        measured (no technique planned).
    """

    asset: str
    mesh: str
    material: str
    techniques: tuple[str, ...]
    params: dict = field(default_factory=dict)
    reasons: tuple[str, ...] = ()
    measures: dict = field(default_factory=dict)
    pilot: dict = field(default_factory=dict)
    lambert_check: dict = field(default_factory=dict)

    @property
    def key(self) -> str:
        """``mesh/material``: what the budget check's picks are keyed on."""
        return f"{self.mesh}/{self.material}"

    def to_json(self) -> dict:
        return {"asset": self.asset, "mesh": self.mesh, "material": self.material,
                "techniques": list(self.techniques), "params": self.params, "reasons": list(self.reasons),
                "measures": self.measures, **({"pilot": self.pilot} if self.pilot else {}),
                **({"lambert_check": self.lambert_check} if self.lambert_check else {})}


def plan_asset(path: str | Path, options: BakeOptions) -> list[PlanEntry]:
    """The plan of every (mesh, material) of the asset at `path` (module docstring).

    Raises
    ------
    AssetError, MaterialError, ValueError
        As the bake would: unreadable files, no scale, bad materials.
    """
    path = Path(path)
    clean = clean_scene(load_scene(str(path), options.allow_roots))
    mm_per_unit, _ = resolve_scale_mm(clean.scene, options.scale_mm)
    assignment = assign_materials(clean.scene, options, mm_per_unit)
    instances = assignment.scene.mesh_instances()
    entries = []
    for mi, mesh in enumerate(assignment.scene.meshes):  # primitives without a material got one
        used = sorted({p.material for p in mesh.primitives if p.material is not None})
        if not used:
            continue
        surface = clean.surfaces[mi]
        mesh_mm = mm_per_unit * instance_scale(clean.scene, mi, [])
        diagonal = float(np.linalg.norm(np.ptp(surface.positions, axis=0)))
        thickness = None
        for m in used:
            material = assignment.materials.get(m)
            name = assignment.scene.materials[m].name
            if material is None:
                entries.append(PlanEntry(str(path), mesh.name, name, (), {},
                                         (f"opaque: {assignment.reasons.get(m, 'no scattering material')}",)))
                continue
            if thickness is None:  # one thickness bake per mesh, only for translucent meshes
                # as the bake's thickness stage: hard edges where the normals are split
                split = np.concatenate([p.normals for p in clean.scene.meshes[mi].primitives])
                thickness = bake_thickness(surface.positions, surface.faces, surface.normals, cap=diagonal,
                                           split_normals=(np.concatenate(surface.weld), split)).thickness
            entry = decide(str(path), mesh.name, name, material, mesh.deforming, options, surface, thickness, mesh_mm)
            entries.append(with_pilot(entry, surface, mesh_mm, material, mesh.deforming, options,
                                      (instances.get(mi) or [None])[0]))
    return entries


def with_pilot(entry: PlanEntry, surface: Surface, mesh_mm: float, material, deforming: bool, options: BakeOptions,
               world: np.ndarray | None = None, pick: int | None = None, measure=None) -> PlanEntry:
    """`entry` after the pilot (`plan_pilot`) when it plans a technique, `entry` itself otherwise:
    under `options.budget_rmse` with the candidate it chooses (`piloted`), and either way with the
    fallback alone when that does not beat best-fit Lambert (`lambert_verdict`).

    Parameters
    ----------
    world : (4, 4) float64, optional
        The mesh's first instance's world matrix.
    pick : int, optional
        The budget check's candidate to bake instead of the pilot's choice.
    measure : callable, optional
        Called with `plan_pilot.run_pilot`'s arguments in its place (the bake caches it as a stage).
    """
    if not entry.techniques:
        return entry
    budget, vertices = options.budget_rmse, len(surface.positions)
    if budget is None:
        found = [planned_candidate(entry.techniques[0], entry.params, options, vertices, "planned")]
    else:
        found = candidates(entry.techniques[0], entry.params, options, vertices, deforming)
    pilot = (measure or run_pilot)(found, surface, mesh_mm, material, options, budget, vertices, world)
    return lambert_verdict(entry if budget is None else piloted(entry, pilot, budget, pick), pilot, pick,
                           options.lambert_margin)


def requested_checks(mesh: str, name: str, techniques: tuple[str, ...], surface: Surface, mesh_mm: float, material,
                     options: BakeOptions, world: np.ndarray | None = None, measure=None) -> list[dict]:
    """`lambert_record`s of the `techniques` the user named (``--techniques T``) on material `name`
    of `mesh`, measured as the planner's are, but all shipped: the user asked for them. Those
    without a pilot (``pilot_item``: kernels, spectral) are not measured here; ``--report``
    verifies them on the full asset.

    Parameters
    ----------
    surface : Surface
        The mesh's welded surface (file units).
    world : (4, 4) float64, optional
        The mesh's first instance's world matrix.
    measure : callable, optional
        As in `with_pilot`.
    """
    vertices = len(surface.positions)
    records = []
    for t in techniques:
        if hasattr(technique(t), "pilot_item"):  # one pilot each: a technique dropped leaves the others' cached
            found = [planned_candidate(t, {}, options, vertices, "requested")]
            # no budget: a budget only checks what the user named
            pilot = (measure or run_pilot)(found, surface, mesh_mm, material, options, None, vertices, world)
            records.append(lambert_record(mesh, name, pilot, 0, options.lambert_margin, True))
    return records


def planned_candidate(name: str, params: dict, options: BakeOptions, vertices: int, why: str) -> Candidate:
    """Technique `name` as the bake runs it under `options` with the plan's `params`, a pilot
    candidate labelled ``"<name> (<why>...)"``, for a mesh of `vertices` welded vertices.

    prt's pilot spends a byte budget on the full asset's reference points (`prt_pilot`); a bake
    without one spends its reference fraction (at least its floor), so the candidate gets the least
    budget that buys as many points."""
    merged = options.merged(params)
    if name != "prt" or merged.prt_byte_budget is not None:
        return Candidate(name, dict(params), f"{name} ({why})")
    prt = merged.technique_options("prt")
    points = min(vertices, max(3, prt.reference_floor, round(prt.reference_fraction * vertices)))
    ds = direction_set(prt.directions)

    def held(budget: float) -> int:
        try:
            return budget_reference_count(budget, vertices, ds, prt.sh_order, prt.tables, prt.weight_bits,
                                          prt.detail_order)
        except ValueError:  # not even 3 points
            return 0

    low, high = 0.0, 1.0
    while held(high) < points:
        low, high = high, 2.0 * high
    for _ in range(40):  # the count rises one point at a time with the budget: the least that holds them
        middle = 0.5 * (low + high)
        low, high = (low, middle) if held(middle) >= points else (middle, high)
    return Candidate(name, {**params, "prt_byte_budget": high, "prt_reference_floor": 0},
                     f"{name} ({why}, {points} reference points)")


def lambert_record(mesh: str, name: str, pilot, at: int, margin: float, shipped: bool) -> dict:
    """What the pilot (`plan_pilot.Pilot`) measured of its candidate `at` on material `name` of
    `mesh` against best-fit Lambert: ``mesh``, ``material``, ``technique``, ``label``, ``params``
    (the candidate's), ``vertices`` (the subsample's), ``reference``, ``rmse_object``,
    ``lambert_rmse_object``, ``margin``, ``beats_lambert`` (by `margin`), ``shipped``."""
    c, row = pilot.candidates[at], pilot.rows[at]
    return {"mesh": mesh, "material": name, "technique": c.technique, "label": c.label, "params": dict(c.params),
            "vertices": pilot.vertices, "reference": pilot.reference, "rmse_object": row["rmse_object"],
            "lambert_rmse_object": row["lambert_rmse_object"], "margin": margin,
            "beats_lambert": row["beats_lambert"], "shipped": shipped}


def worse_than_lambert(report: dict) -> list[dict]:
    """The techniques a bake `report` shipped that its pilot measured worse than best-fit Lambert
    (not better at all: `plan_pilot.beats_lambert` with no margin), each its `plan.lambert_record`
    (``--techniques auto`` ships none it measured so; a technique the user named may be)."""
    return [c for c in report.get("lambert_checks", [])
            if c["shipped"] and not beats_lambert(c["rmse_object"], c["lambert_rmse_object"], 0.0)]


def lambert_line(marks: list[dict], measured: str) -> str | None:
    """One line counting `marks` (each ``asset``, ``technique``, ``rmse_object``,
    ``lambert_rmse_object``, and ``mesh`` and ``material`` where measured per material) and naming
    each with both figures, `measured` saying where (e.g. ``"on the pilot's subsample"``); None for
    none."""
    if not marks:
        return None
    named = "; ".join(f"{Path(m['asset']).name}{' ' + m['mesh'] + '/' + m['material'] if 'mesh' in m else ''} "
                      f"{m['technique']} {m['rmse_object']:.4f} against {m['lambert_rmse_object']:.4f}" for m in marks)
    return (f"{len(marks)} technique{'s' if len(marks) > 1 else ''} worse than best-fit Lambert (object RMSE "
            f"{measured}): {named}")


def lambert_verdict(entry: PlanEntry, pilot, pick: int | None, margin: float) -> PlanEntry:
    """`entry` (its technique the pilot's candidate `pick`, or its choice) with the pilot's figures
    against best-fit Lambert in a reason and its `lambert_check`, or, when they do not show it
    under (1 - `margin`) x Lambert's, the standard fallback alone. A candidate the budget check
    picked that the pilot never measured stands as it is."""
    at = pilot.chosen if pick is None else pick
    if at >= len(pilot.rows):
        return entry
    row = pilot.rows[at]
    record = lambert_record(entry.mesh, entry.material, pilot, at, margin, row["beats_lambert"])
    figures = (f"pilot on {pilot.vertices} vertices, object RMSE against the {pilot.reference} reference: "
               f"{pilot.candidates[at].label} {row['rmse_object']:.4f}, "
               f"best-fit Lambert {row['lambert_rmse_object']:.4f}")
    if row["beats_lambert"]:
        return replace(entry, reasons=entry.reasons + (f"{figures}: under {1 - margin:g} x Lambert's, shipped",),
                       lambert_check=record)
    # the pilot prefers a candidate that beats Lambert and holds its bytes: its own choice failing means none did
    others = " (nor does any other that holds its bytes)" if pick is None and len(pilot.rows) > 1 else ""
    return replace(entry, techniques=(), params={}, lambert_check=record,
                   reasons=entry.reasons + (f"{figures}: not under {1 - margin:g} x Lambert's{others}; the standard "
                                            "fallback only",))


def piloted(entry: PlanEntry, pilot, budget: float, pick: int | None = None) -> PlanEntry:
    """`entry` with the technique and parameters of the pilot's candidate (`plan_pilot.Pilot`),
    its own choice or, after the check on the full asset, candidate `pick`; the reason lists what
    the pilot measured."""
    i = pilot.chosen if pick is None else pick
    c = pilot.candidates[i]
    measured = ", ".join(f"{r['label']} {r['rmse_image']:.4f}" for r in pilot.rows if r["rmse_image"] is not None)
    if pick is not None and pick != pilot.chosen:
        verdict = f"{c.label}, moved from the pilot's {pilot.candidates[pilot.chosen].label} by the check on the full asset"
    elif pilot.met:
        verdict = f"{c.label}, the cheapest within it"
    else:
        verdict = f"none within it; {c.label}, the least RMSE"
    moved = c.technique not in entry.techniques and c.technique in PHYSICS_LIMITS
    reason = (f"pilot on {pilot.vertices} vertices, image RMSE against the {pilot.reference} reference (budget {budget:g}): "
              f"{measured}; {verdict}" + (f"; {PHYSICS_LIMITS[c.technique]}" if moved else ""))
    params = {**entry.params, **c.params} if c.technique in entry.techniques else dict(c.params)
    record = {"budget": budget, "vertices": pilot.vertices, "reference": pilot.reference,
              "candidates": [{"label": k.label, "technique": k.technique, "params": k.params} for k in pilot.candidates],
              "rows": [dict(r) for r in pilot.rows], "chosen": pilot.chosen, "met": pilot.met, "pick": i}
    return replace(entry, techniques=(c.technique,), params=params, reasons=entry.reasons + (reason,), pilot=record)


def area_median(values: np.ndarray, areas: np.ndarray) -> float:
    """The median of per-vertex `values` (n,) weighted by the vertices' `areas` (n,): the value half
    the surface is under (a vertex count would let densely meshed thin rims outvote big faces)."""
    order = np.argsort(values)
    cumulative = np.cumsum(np.asarray(areas, dtype=np.float64)[order])
    if not cumulative[-1] > 0:
        return float(np.median(values))
    return float(np.asarray(values)[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def decide(asset: str, mesh: str, name: str, material, deforming: bool, options: BakeOptions, surface: Surface,
           thickness: np.ndarray, mesh_mm: float) -> PlanEntry:
    """The plan of one translucent `material` of a mesh: the first rule of the module docstring that
    applies, from the mesh's welded `surface`, its per-vertex `thickness` (n,) in file units and
    its mm per unit."""
    extent = np.ptp(surface.positions, axis=0) * mesh_mm
    diagonal_mm, longest_mm = float(np.linalg.norm(extent)), float(extent.max())
    thickness_mm = area_median(thickness, surface.vertex_areas) * mesh_mm
    vertices = len(surface.positions)
    params = profile_for(material)
    sigma_tr = np.asarray(params.sigma_tr, dtype=np.float64)
    diffusion = 1.0 / np.maximum(sigma_tr, 1e-12)
    radius = float(radius_holding(params, 0.5).max())
    texel = diagonal_mm / options.atlas_resolution
    measures = {"diagonal_mm": diagonal_mm, "median_thickness_mm": thickness_mm,
                "diffusion_mm": [float(min(d, 1e12)) for d in diffusion], "median_radius_mm": radius,
                "texel_mm": texel}

    free_path = float(np.max(1.0 / material.sigma_t_prime))
    measures["free_path_mm"] = free_path
    crossed = (f"; the median thickness {thickness_mm:.3g} mm is under {FEW_FREE_PATHS:g} reduced mean free paths "
               f"({FEW_FREE_PATHS:g} x {free_path:.3g} mm): light crosses it in a few scatterings, which diffusion does "
               f"not model, so against physics every technique may lose to best-fit Lambert (docs/fidelity.md)"
               if thickness_mm < FEW_FREE_PATHS * free_path else "")

    def entry(techniques, reason, extra=None):
        limits = "".join(f"; {PHYSICS_LIMITS[t]}" for t in techniques if t in PHYSICS_LIMITS)
        limits += crossed if techniques else ""
        return PlanEntry(asset, mesh, name, tuple(techniques), extra or {}, (reason + limits,), measures)

    if radius < texel:
        return entry((), f"nearly opaque at this scale: half of R_d lies within {radius:.3g} mm, under the "
                         f"{texel:.3g} mm texel; fallback only (base colour R_d)")
    if options.lpv_field != "homogeneous":
        cells = math.ceil(longest_mm * float(sigma_tr.max()) / LPV_COARSE)
        resolution = int(min(max(cells, 16), LPV_MAX_RESOLUTION))
        capped = "" if cells <= LPV_MAX_RESOLUTION else f" (capped: {cells} wanted)"
        return entry(("lpv",), f"heterogeneous medium ({options.lpv_field}): lpv, grid {resolution} so that "
                               f"sigma_tr * cell <= {LPV_COARSE:g}{capped}",
                     {"lpv_resolution": resolution, "lpv_field": options.lpv_field})
    if deforming:
        return entry(("screen",), "deforming mesh (skin or morph targets): no per-vertex bake; screen")
    widest = float(diffusion.max())
    if thickness_mm < THIN * widest or diagonal_mm < SMALL * widest:
        why = (f"thin or small for its diffusion length {widest:.3g} mm (median thickness {thickness_mm:.3g} mm, "
               f"diagonal {diagonal_mm:.3g} mm): light crosses it")
        budget = options.max_bytes_per_vertex
        if budget is None:
            return entry(("prt",), f"{why}; prt")
        try:  # the budget, not the reference floor, sets the reference points
            budget_reference_count(budget, vertices, direction_set(options.prt_directions), options.prt_sh_order,
                                   options.prt_tables, options.prt_weight_bits, options.prt_detail_order)
        except ValueError as error:
            least = str(error).rsplit("give at least ", 1)[-1]
            return entry(("screen",), f"{why}, but prt needs at least {least} bytes per vertex here, over the "
                                      f"{budget:g} allowed; screen, nothing per vertex")
        return entry(("prt",), f"{why}; prt within {budget:g} bytes per vertex",
                     {"prt_byte_budget": float(budget), "prt_reference_floor": 0})
    # thickness x σ_tr, not over the widest length 1/σ_tr: no quotient of a length that may round to 0
    lengths = thickness_mm * float(np.maximum(sigma_tr, 1e-12).min())
    return entry(("screen",), f"thick and local: median thickness {lengths:.3g} diffusion lengths "
                              f"({widest:.3g} mm); screen, nothing per vertex")
