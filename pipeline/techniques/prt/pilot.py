"""prt: the planner's pilot (`technique.Technique`'s pilot hooks).

Candidates: byte budgets per vertex (`PRT_BUDGETS`, capped by ``max_bytes_per_vertex``), each with
K light directions from `PRT_DIRECTIONS` (within `PRT_Q_BYTES` of light integrals). Each sets the
reference-point count on the full asset (`prt_compress.budget_reference_count`); the pilot uses the
same count, since the count over the same area sets the points' spacing, which sets the
interpolation error.
"""

from __future__ import annotations

from dataclasses import replace

from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.techniques.prt.compress import budget_reference_count, compress_prt
from sssbake.pipeline.techniques.prt.precompute import PRT_PRECOMPUTE_DEFAULTS, precompute_prt
from sssbake.pipeline.techniques.technique import Candidate

PRT_BUDGETS = (6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0)
#: Light directions K tried at each budget: fewer leave bytes for more reference points, more
#: interpolate between directions better; neither wins everywhere (benchmarks/README.md#pilot-prt-directions).
PRT_DIRECTIONS = (100, 200, 400)
#: Most bytes of prt's float64 light integrals q (3 n K) a candidate's bake may hold: the bake keeps
#: q and its compression error together (benchmarks/README.md#pilot-prt-directions).
PRT_Q_BYTES = 4e9


class PrtPilot:
    """Byte budgets and light directions (module docstring); every candidate is measured (the
    budget check scales the pilot's figures)."""

    def pilot_candidates(self, params: dict, options, vertices: int, deforming: bool) -> list[Candidate]:
        prt = options.technique_options("prt")
        ceiling = options.max_bytes_per_vertex
        budgets = [b for b in PRT_BUDGETS if ceiling is None or b < ceiling] + ([ceiling] if ceiling else [])
        out, seen = [], set()
        for b in budgets:
            for k in sorted(set(PRT_DIRECTIONS) | {prt.directions}):  # at equal bytes, fewer K bake faster
                if 3 * vertices * k * 8 > PRT_Q_BYTES and k > min(PRT_DIRECTIONS):
                    continue
                try:
                    count = budget_reference_count(b, vertices, direction_set(k), prt.sh_order, prt.tables,
                                                   prt.weight_bits, prt.detail_order)
                except ValueError:  # not even 3 points fit
                    continue
                count = min(count, vertices)
                if (k, count) not in seen:
                    seen.add((k, count))
                    sets = {"prt_directions": k, "prt_byte_budget": float(b), "prt_reference_floor": 0}
                    out.append(Candidate("prt", sets, f"prt <= {b:g} B/vertex, K = {k} ({count} reference points)"))
        return out

    def pilot_item(self, options, surface: Surface, mm_per_unit: float, material: Material, vertices: int,
                   memo: dict) -> tuple[dict, bool]:
        """The compressed prt at the full asset's reference-point count; its light integrals are
        computed once per K for all budgets (`memo`). Its bytes do not hold where the
        simplification stopped above that count (thin slabs)."""
        prt = options.technique_options("prt")
        integrals = memo.setdefault("q", {})  # K -> (direction set, q)
        if prt.directions not in integrals:
            ds = direction_set(prt.directions)
            scatter = replace(PRT_PRECOMPUTE_DEFAULTS.scatter, energy_dropped=prt.energy_dropped)
            integrals[prt.directions] = ds, precompute_prt(surface, mm_per_unit, material, ds.directions,
                                                           replace(PRT_PRECOMPUTE_DEFAULTS, scatter=scatter)).q
        ds, q = integrals[prt.directions]
        # the full asset's count: the same spacing over the same area
        count = budget_reference_count(prt.byte_budget, vertices, ds, prt.sh_order, prt.tables, prt.weight_bits,
                                       prt.detail_order)
        compress = replace(prt.compress(), reference_count=min(count, len(surface.positions)), byte_budget=None,
                           reference_floor=0)
        data = compress_prt(q, ds, surface.positions, surface.faces, material.eta, compress)
        return {"prt": data}, len(data.ref_vertices) <= compress.reference_count

