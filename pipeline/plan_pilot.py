"""The planner's pilot (``--budget-rmse``): the parameters of a planned technique chosen by measuring
them on a subsample of the mesh, so the bake spends the fewest bytes and seconds that meet the
error budget; `plan_check` then checks the choice on the full asset.

The candidates of a technique run from cheap to dear (`candidates`):

* prt: byte budgets per vertex (`PRT_BUDGETS`, capped by ``max_bytes_per_vertex``), each with
  K light directions from `PRT_DIRECTIONS` (within `PRT_Q_BYTES` of light integrals). Each sets the reference-point count on the full asset
  (`prt_compress.budget_reference_count`); the pilot uses the same count, since the count over the
  same area sets the points' spacing, which sets the interpolation error;
* screen: importance samples N (`SCREEN_SAMPLES`); nothing per vertex, N costs frame time. When
  no N meets the budget (light crossing a thin part, which screen space misses), prt's
  candidates follow, unless the mesh deforms;
* lpv: grid resolutions (`LPV_RESOLUTIONS`) from the planner's on.

The pilot renders each candidate's runtime on the subsample (`PILOT_VERTICES`, `PILOT_SIZE`²,
verify's light and camera) against the offline reference on the same subsample and takes the
first whose image RMSE is within the budget (screen and prt measure every candidate, for the
check's estimates; lpv stops there, its grids being dear). A heterogeneous lpv medium has no
closed-form reference: each grid is measured against verify's reference for it, the same field at
twice the resolution (`verify.lpv_reference`). When none meets it, the candidate with the least
RMSE is chosen, and the reason says the budget was not met.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .clean import Surface, vertex_areas
from .directions import direction_set
from .image_metrics import rmse, shared_exposure
from .lpv_layout import lpv_grid_from_tables, lpv_source_from_tables
from .lpv_propagate import LPV_DEFAULTS
from .lpv_stage import bake_lpv
from .materials import Material
from .options import BakeOptions
from .prt_compress import budget_reference_count, compress_prt
from .prt_precompute import PRT_PRECOMPUTE_DEFAULTS, precompute_prt
from .reference import Light, reference_scattering
from .screen_samples import screen_samples
from .simplify import simplify
from .verify import DEFAULT_LIGHT, LPV_SELF_REFERENCE, lpv_reference

#: Vertices of the subsample the pilot measures on.
PILOT_VERTICES = 4000
#: Side of the pilot's images, pixels; the check on the full asset renders at the same size, so
#: their figures compare.
PILOT_SIZE = 160
PRT_BUDGETS = (6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0)
#: Light directions K tried at each budget: fewer leave bytes for more reference points, more
#: interpolate between directions better. Neither wins everywhere: on the armadillo (potato, verify's
#: light) 32 B/vertex measured 0.0179 at K = 100, 0.0211 at 200 and 0.0160 at 400.
PRT_DIRECTIONS = (100, 200, 400)
#: Most bytes of prt's float64 light integrals q (3 n K) a candidate's bake may hold: the bake keeps
#: q and its compression error together, and K = 200 on the 800k-vertex dragon (3.8 GB) is what
#: this 24 GB machine measured to fit.
PRT_Q_BYTES = 4e9
SCREEN_SAMPLES = (8, 16, 32, 64)
LPV_RESOLUTIONS = (16, 24, 32, 48, 64, 96, 128)


@dataclass(frozen=True)
class Candidate:
    """One configuration the pilot may choose.

    Attributes
    ----------
    technique : str
    params : dict
        The bake options it sets on the full asset.
    label : str
        What a reader is told it is (e.g. ``"prt <= 12 B/vertex (412 reference points)"``).
    """

    technique: str
    params: dict
    label: str


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
        ``"dipole"`` or verify's `LPV_SELF_REFERENCE` (heterogeneous lpv).
    """

    candidates: tuple
    rows: tuple
    chosen: int
    met: bool
    vertices: int
    reference: str


def candidates(technique: str, params: dict, options: BakeOptions, vertices: int, deforming: bool) -> list[Candidate]:
    """The configurations of `technique` (with the planner's `params`) the pilot tries, cheapest
    first, for a mesh of `vertices` welded vertices (module docstring)."""
    if technique == "screen":
        out = [Candidate("screen", {"screen_samples": n}, f"screen, N = {n}") for n in SCREEN_SAMPLES]
        return out + ([] if deforming else candidates("prt", {}, options, vertices, deforming))
    if technique == "prt":
        ceiling = options.max_bytes_per_vertex
        budgets = [b for b in PRT_BUDGETS if ceiling is None or b < ceiling] + ([ceiling] if ceiling else [])
        out, seen = [], set()
        for b in budgets:
            for k in sorted(set(PRT_DIRECTIONS) | {options.prt_directions}):  # at equal bytes, fewer K bake faster
                if 3 * vertices * k * 8 > PRT_Q_BYTES and k > min(PRT_DIRECTIONS):
                    continue
                try:
                    count = budget_reference_count(b, vertices, direction_set(k), options.prt_sh_order,
                                                   options.prt_tables, options.prt_weight_bits, options.prt_detail_order)
                except ValueError:  # not even 3 points fit
                    continue
                count = min(count, vertices)
                if (k, count) not in seen:
                    seen.add((k, count))
                    out.append(Candidate("prt", {"prt_directions": k, "prt_byte_budget": float(b), "prt_reference_floor": 0},
                                         f"prt <= {b:g} B/vertex, K = {k} ({count} reference points)"))
        return out
    if technique == "lpv":
        start = params.get("lpv_resolution", options.lpv_resolution)
        steps = [start] + [r for r in LPV_RESOLUTIONS if r > start]
        return [Candidate("lpv", {**params, "lpv_resolution": r}, f"lpv, grid {r}") for r in steps]
    raise ValueError(f"pilot: no candidates for technique {technique!r}")


def pilot_surface(surface: Surface, vertices: int = PILOT_VERTICES) -> Surface:
    """`surface` simplified to about `vertices` vertices (itself when not much larger), each kept
    vertex with its own normal."""
    if len(surface.positions) <= 1.5 * vertices:
        return surface
    # quadric-optimal positions: the closer surface (screen's error on the bunny's 4k-vertex
    # subsample: 0.035 against 0.044 with the kept vertices' own positions; 0.023 on all 35k)
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
        World direction towards the light (verify's `DEFAULT_LIGHT` by default).
    """
    from .render import Renderer, RenderLight, fit_camera

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
    # a heterogeneous medium has no closed-form reference: each grid against verify's, the same field at 2x
    veined = found[0].technique == "lpv" and options.lpv_field != "homogeneous"
    try:
        if not veined:
            q = reference_scattering(small, mm_per_unit, material, Light("directional", tuple(local)))
            reference, mask = renderer.render([{**base, "q": q.T}], camera, lit)
            exposure = shared_exposure(reference, mask)
        maker = _Items(small, mm_per_unit, material, options, vertices)
        rows, chosen, met = [], None, False
        for i, c in enumerate(found):
            t = time.perf_counter()
            item = maker.item(c)
            seconds = time.perf_counter() - t
            if veined:
                reference, mask = renderer.render([{**base, **maker.finer(item)}], camera, lit)
                exposure = shared_exposure(reference, mask)
            error = rmse(renderer.render([{**base, **item}], camera, lit)[0], reference, exposure)
            rows.append({"label": c.label, "technique": c.technique, "rmse_image": error, "seconds": seconds,
                         "holds_bytes": maker.holds_bytes})
            if error <= budget and maker.holds_bytes and chosen is None:
                chosen, met = i, True
            if chosen is not None and c.technique == "lpv":  # lpv grids are dear: stop at the first within
                break
    finally:
        renderer.release()
    if chosen is None:  # the least RMSE, among the candidates that held their bytes if any did
        held = [i for i, r in enumerate(rows) if r["holds_bytes"]] or range(len(rows))
        chosen = min(held, key=lambda i: rows[i]["rmse_image"])
    return Pilot(tuple(found), tuple(rows), chosen, met, len(small.positions), LPV_SELF_REFERENCE if veined else "dipole")


class _Items:
    """Render items (`render.Renderer`) of candidates on the pilot's surface, each made by its
    technique's own stage code; prt's light integrals are computed once per K for all budgets."""

    def __init__(self, surface: Surface, mm_per_unit: float, material: Material, options: BakeOptions, vertices: int):
        self.surface, self.mm, self.material, self.options, self.vertices = surface, mm_per_unit, material, options, vertices
        self._q = {}  # prt's light integrals per K
        self.lpv_source = None
        # whether the last item kept to its bytes: prt's simplification can stop short of the count
        # a byte budget allows (thin slabs), and then it takes more
        self.holds_bytes = True

    def finer(self, item: dict) -> dict:
        """The self-convergence reference of the lpv `item` made last, as verify draws it
        (`verify.lpv_reference`)."""
        grid, scales, steps, _ = lpv_reference(self.surface, self.lpv_source, item["lpv"], item["lpv_steps"])
        return {"lpv": grid, "lpv_matrices": item["lpv_matrices"], "lpv_scales": scales, "lpv_steps": steps}

    def item(self, c: Candidate) -> dict:
        o = self.options.merged(c.params)
        if c.technique == "screen":
            self.holds_bytes = True
            return {"screen": screen_samples(self.material, o.screen()), "mm_per_unit": self.mm}
        if c.technique == "lpv":
            baked = bake_lpv(self.surface, self.mm, self.material, o.lpv_grid(), o.lpv_field, o.lpv_marble(),
                             o.lpv_max_steps)
            grid, matrices, scales = lpv_grid_from_tables(baked.tables, self.mm)
            self.lpv_source, self.holds_bytes = lpv_source_from_tables(baked.tables), True
            return {"lpv": grid, "lpv_matrices": matrices, "lpv_scales": scales, "lpv_steps": LPV_DEFAULTS.steps}
        if o.prt_directions not in self._q:
            ds = direction_set(o.prt_directions)
            scatter = replace(PRT_PRECOMPUTE_DEFAULTS.scatter, energy_dropped=o.prt_energy_dropped)
            self._q[o.prt_directions] = ds, precompute_prt(self.surface, self.mm, self.material, ds.directions,
                                                           replace(PRT_PRECOMPUTE_DEFAULTS, scatter=scatter)).q
        ds, q = self._q[o.prt_directions]
        n = len(self.surface.positions)
        # the full asset's count: the same spacing over the same area
        count = budget_reference_count(o.prt_byte_budget, self.vertices, ds, o.prt_sh_order, o.prt_tables,
                                       o.prt_weight_bits, o.prt_detail_order)
        compress = replace(o.prt_compress(), reference_count=min(count, n), byte_budget=None, reference_floor=0)
        prt = compress_prt(q, ds, self.surface.positions, self.surface.faces, self.material.eta, compress)
        self.holds_bytes = len(prt.ref_vertices) <= compress.reference_count
        return {"prt": prt}
