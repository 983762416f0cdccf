"""The prt stage of a bake: directions → precompute → compress, for one mesh's surface."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .clean import Surface
from .directions import direction_set
from .materials import Material
from .prt_compress import PrtCompressOptions, bytes_per_vertex, compress_prt, decode_at_directions
from .prt_data import PrtData
from .prt_precompute import PRT_PRECOMPUTE_DEFAULTS, precompute_prt

@dataclass(frozen=True, eq=False)
class PrtBake:
    """The compressed data of one mesh and what it cost.

    Attributes
    ----------
    prt : PrtData
    report : dict
        Seconds per step, gather radius and dropped fraction, bytes per vertex by block, and the
        compression error of q (rms and max, relative to the largest q).
    """

    prt: PrtData
    report: dict = field(default_factory=dict)


def bake_prt(surface: Surface, mm_per_unit: float, material: Material, directions: int,
             energy_dropped: float, compress: PrtCompressOptions) -> PrtBake:
    """Run the prt technique on one welded surface."""
    t = time.perf_counter()
    ds = direction_set(directions)
    scatter = replace(PRT_PRECOMPUTE_DEFAULTS.scatter, energy_dropped=energy_dropped)
    integrals = precompute_prt(surface, mm_per_unit, material, ds.directions,
                               replace(PRT_PRECOMPUTE_DEFAULTS, scatter=scatter))
    t_compress = time.perf_counter()
    prt = compress_prt(integrals.q, ds, surface.positions, surface.faces, material.eta, compress)
    seconds = {**integrals.seconds, "compress": time.perf_counter() - t_compress}
    error = decode_at_directions(prt)
    error -= integrals.q  # in place: q-sized arrays are the stage's largest
    peak = max(float(integrals.q.max()), 1e-300)
    report = {
        "directions": directions,
        "mode": compress.mode,
        "referencePoints": int(len(prt.ref_codes)),
        "shOrder": prt.sh_order,
        "detailOrder": prt.detail_order,
        "weights": compress.weights,
        "tables": compress.tables,
        "refine": compress.refine,
        "weightBits": prt.weight_bits,
        "byteBudget": compress.byte_budget,
        "radiusMm": integrals.radius_mm.tolist(),
        "droppedFraction": integrals.dropped_fraction.tolist(),
        "qMax": peak,
        "compressionRmsOverMax": float(np.sqrt(np.vdot(error, error) / error.size) / peak),
        "compressionMaxOverMax": float(max(error.max(), -error.min()) / peak),
        "bytesPerVertex": bytes_per_vertex(prt),
        "seconds": {k: round(v, 4) for k, v in seconds.items()} | {"total": round(time.perf_counter() - t, 4)},
        "gather": {k: v for k, v in integrals.stats.items() if k in ("entries", "operator_bytes", "levels", "cell_mm")},
    }
    return PrtBake(prt, report)
