"""prt: what its bake will hold and take, forecast before its gather is built, checked against
what the asset may still spend (`technique.Budget`).

prt is the one stage whose memory grows faster than the mesh: every level of its gather's
hierarchy adds ~75 clusters per vertex, and the levels grow as log n (benchmarks/README.md#bake-scaling).
The forecast builds 2 % of the gather's rows (`scatter_forecast`) and adds the light integrals q
and the gather's temporaries. Over budget, the error names the knobs that bound it, each with its
own forecast: fewer light directions (q), a larger dropped energy (fewer levels and pairs).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from sssbake.pipeline.core.profile import Profile
from sssbake.pipeline.core.scatter_forecast import ScatterForecast, scatter_forecast
from sssbake.pipeline.core.scatter_operator import ScatterPlan, scatter_plan
from sssbake.pipeline.techniques.technique import Budget

#: Larger dropped energies the error tries when the gather alone does not fit (each one plans
#: the hierarchy again: a few seconds per 100k vertices).
ENERGY_STEPS = (0.03, 0.1, 0.3)
#: Fewer light directions the error tries when q does not fit.
DIRECTION_STEPS = (100, 50)

_GIB = 2.0**30


@dataclass(frozen=True)
class PrtForecast:
    """Attributes
    ----------
    peak_bytes : int
        The stage's most at once: the gather's build, or the gather with q and a block's
        temporaries on each thread.
    seconds : float
        Building the gather and gathering the K directions (the plan's time, the visibility and
        the compression not included).
    entries : int
        The gather's stored values (`ScatterOperator.nnz`).
    directions : int
        K.
    gather : ScatterForecast
        The gather's own forecast (K does not change it).
    """

    peak_bytes: int
    seconds: float
    entries: int
    directions: int
    gather: ScatterForecast = field(repr=False)

    def to_json(self) -> dict:
        return {"peak_bytes": self.peak_bytes, "seconds": round(self.seconds, 2), "entries": self.entries,
                "peak_gib": round(self.peak_bytes / _GIB, 3)}


def prt_forecast(plan: ScatterPlan, directions: int) -> PrtForecast:
    """The forecast for gathering `directions` light directions through `plan`'s gather."""
    return _with_directions(scatter_forecast(plan), plan, directions)


def _with_directions(f: ScatterForecast, plan: ScatterPlan, directions: int) -> PrtForecast:
    """The gather's forecast `f` with q and the gather's temporaries for `directions` directions."""
    n = len(plan.positions)
    item = 4 if plan.options.float32 else 8
    q = 3 * n * directions * item
    block = min(plan.options.block, directions)
    # per thread: the block's signal (float64 and cast), its result and its moments
    temporaries = plan.workers * n * block * (8 + item + 2 * 3 * item)
    peak = max(f.build_peak_bytes, f.operator_bytes + q + temporaries)
    return PrtForecast(int(peak), f.build_seconds + directions * f.apply_seconds, f.entries, directions, f)


def check_budget(forecast: PrtForecast, budget: Budget | None, plan: ScatterPlan, positions_mm: np.ndarray,
                 faces: np.ndarray, normals: np.ndarray, params: Profile) -> None:
    """Raise ValueError (one line: the forecast, the limit, the knobs that would fit) when
    `forecast` (of `plan`'s gather, planned from `positions_mm`, `faces`, `normals` and `params`)
    is over `budget`."""

    def fits(f: PrtForecast) -> bool:
        return ((budget.memory_bytes is None or f.peak_bytes <= budget.memory_bytes)
                and (budget.seconds is None or f.seconds <= budget.seconds))

    if budget is None or fits(forecast):
        return
    over_memory = budget.memory_bytes is not None and forecast.peak_bytes > budget.memory_bytes
    what = (f"{forecast.peak_bytes / _GIB:.1f} GiB, over the {budget.memory_bytes / _GIB:.3g} GiB this asset has left "
            "under --asset-memory" if over_memory else
            f"{forecast.seconds:.0f} s, over the {budget.seconds:.0f} s this asset has left under --asset-timeout")
    knobs = []
    for k in (k for k in DIRECTION_STEPS if k < forecast.directions):
        f = _with_directions(forecast.gather, plan, k)
        if fits(f):
            knobs.append(f"--prt-directions {k} ({_brief(f)})")
            break
    for e in (e for e in ENERGY_STEPS if e > plan.options.energy_dropped):
        options = replace(plan.options, energy_dropped=e)
        f = prt_forecast(scatter_plan(positions_mm, faces, normals, params, options), forecast.directions)
        if fits(f):
            knobs.append(f"--prt-energy-dropped {e:g} ({_brief(f)})")
            break
    fit = ", or pass " + " or ".join(knobs) if knobs else "; no fewer directions or larger dropped energy tried fits"
    raise ValueError(f"prt: its gather's {forecast.entries / 1e6:.0f}M entries are forecast to need {what}: "
                     f"raise it{fit}")


def _brief(f: PrtForecast) -> str:
    return f"about {f.peak_bytes / _GIB:.1f} GiB, {f.seconds:.0f} s"

