"""The prt stage of a bake: directions → precompute → compress, for one mesh's surface."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.scatter_operator import scatter_plan
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.baked import VertexAttribute
from sssbake.pipeline.techniques.prt.compress import (
    PrtCompressOptions,
    bytes_per_vertex,
    compress_prt,
    decode_at_directions,
)
from sssbake.pipeline.techniques.prt.data import PrtData
from sssbake.pipeline.techniques.prt.forecast import check_budget, prt_forecast
from sssbake.pipeline.techniques.prt.layout import prt_tables, prt_vertex_attributes
from sssbake.pipeline.techniques.prt.options import PrtOptions
from sssbake.pipeline.techniques.prt.precompute import PRT_PRECOMPUTE_DEFAULTS, precompute_prt
from sssbake.pipeline.techniques.technique import BakeTarget, Budget, TechniqueBake, same_tables

#: Vertices decoded at once for the compression error (3 · 32768 · K float64: 157 MB at K = 200).
ERROR_CHUNK = 32768


def bake_prt(surface: Surface, mm_per_unit: float, material: Material, directions: int,
             energy_dropped: float, compress: PrtCompressOptions, budget: Budget | None = None) -> TechniqueBake:
    """Run the prt technique on one welded surface.

    The gather's hierarchy is planned and its cost forecast first (`forecast.prt_forecast`): over
    `budget`, ValueError names the knobs that would fit, before the gather is built.

    Returns
    -------
    TechniqueBake
        ``data``: the `PrtData`; ``tables``: `prt_tables`; ``report``: seconds per step, gather
        radius and dropped fraction, bytes per vertex by block, the compression error of q (rms
        and max, relative to the largest q) and the forecast.
    """
    t = time.perf_counter()
    ds = direction_set(directions)
    scatter = replace(PRT_PRECOMPUTE_DEFAULTS.scatter, energy_dropped=energy_dropped)
    x, params = surface.positions * mm_per_unit, profile_for(material)
    plan = scatter_plan(x, surface.faces, surface.normals, params, scatter)
    t_forecast = time.perf_counter()
    forecast = prt_forecast(plan, directions)
    check_budget(forecast, budget, plan, x, surface.faces, surface.normals, params)
    t_build = time.perf_counter()
    operator = plan.build()
    del plan  # its pair lists and near field, before q is allocated
    t_gather = time.perf_counter()
    integrals = precompute_prt(surface, mm_per_unit, material, ds.directions,
                               replace(PRT_PRECOMPUTE_DEFAULTS, scatter=scatter), operator)
    del operator
    t_compress = time.perf_counter()
    prt = compress_prt(integrals.q, ds, surface.positions, surface.faces, material.eta, compress)
    seconds = {"plan": t_forecast - t, "forecast": t_build - t_forecast, "operator": t_gather - t_build,
               "visibility": integrals.seconds["visibility"], "gather": integrals.seconds["gather"],
               "compress": time.perf_counter() - t_compress}
    squares, largest = compression_error(prt, integrals.q)
    peak = max(float(integrals.q.max()), 1e-300)
    report = {
        "directions": directions,
        "mode": compress.mode,
        "referencePoints": int(len(prt.ref_codes)),
        "shOrder": prt.sh_order,
        "detailOrder": prt.detail_order,
        "weights": compress.weights,
        # what "auto" chose: shared tables carry a colour per reference point
        "tables": ("shared" if len(prt.ref_scale) else "rgb") if compress.mode == "refs+sh" else compress.tables,
        "refine": compress.refine,
        "weightBits": prt.weight_bits,
        "byteBudget": compress.byte_budget,
        "radiusMm": integrals.radius_mm.tolist(),
        "droppedFraction": integrals.dropped_fraction.tolist(),
        "qMax": peak,
        "compressionRmsOverMax": float(np.sqrt(squares / integrals.q.size) / peak),
        "compressionMaxOverMax": largest / peak,
        "bytesPerVertex": bytes_per_vertex(prt),
        "seconds": {k: round(v, 4) for k, v in seconds.items()} | {"total": round(time.perf_counter() - t, 4)},
        "gather": {k: v for k, v in integrals.stats.items() if k in ("entries", "operator_bytes", "levels", "cell_mm")},
        "forecast": forecast.to_json(),
    }
    return TechniqueBake(prt, prt_tables(prt), report)


def compression_error(prt: PrtData, q: np.ndarray, chunk: int = ERROR_CHUNK) -> tuple[float, float]:
    """Σ (decoded - q)² and max |decoded - q| over every channel, vertex and direction.

    Decoded `chunk` vertices at a time: a whole (3, n, K) float64 error would be the stage's
    largest array (1 GB at 200k vertices, K = 200).

    Parameters
    ----------
    prt : PrtData
    q : (3, n, K) float32 or float64
    chunk : int
    """
    squares, largest = 0.0, 0.0
    for s in range(0, q.shape[1], chunk):
        error = decode_at_directions(prt, slice(s, s + chunk))
        error -= q[:, s:s + chunk]
        squares += float(np.vdot(error, error))
        largest = max(largest, float(np.abs(error).max(initial=0.0)))
    return squares, largest


class PrtStage:
    """prt's bake hooks (`technique.Technique`)."""

    # The compression simplifies the surface to reference points: no prt, no simplification.
    dependent_stages = {"simplify": "no technique that needs reference points ran"}

    def bake(self, target: BakeTarget, options: PrtOptions) -> TechniqueBake:
        compress = options.compress()
        baked = bake_prt(target.surface, target.mm_per_unit, target.material, options.directions,
                         options.energy_dropped, compress, target.budget)
        total = baked.report["bytesPerVertex"]["total"]
        if compress.byte_budget is None or total <= compress.byte_budget:
            return baked
        return replace(baked, warnings=(
            f"prt takes {total:.1f} B/vertex, over its {compress.byte_budget:g} B/vertex budget: simplification "
            f"stopped at {baked.report['referencePoints']} reference points (edge collapses on thin slabs would flip "
            "faces)",))

    def vertex_attributes(self, result: TechniqueBake, welded: np.ndarray) -> tuple[VertexAttribute, ...]:
        return prt_vertex_attributes(result.data, welded)

    def check_bake(self, result: TechniqueBake, target: BakeTarget, options: PrtOptions) -> None:
        if not isinstance(result.data, PrtData):
            raise ValueError(f"prt: data is a {type(result.data).__name__}, not PrtData")
        if result.data.vertex_count != len(target.surface.positions):
            raise ValueError(f"prt: data over {result.data.vertex_count} vertices, the surface has "
                             f"{len(target.surface.positions)}")
        if not same_tables(result.tables, prt_tables(result.data)):
            raise ValueError("prt: tables are not those of its data")
