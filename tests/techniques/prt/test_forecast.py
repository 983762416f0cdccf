"""prt's forecast and budget: it covers the gather and q, refuses up front over a budget with
the knobs that would fit, and says nothing within it."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.scatter_operator import scatter_plan
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, vertex_areas
from sssbake.pipeline.techniques.prt.compress import PRT_COMPRESS_DEFAULTS
from sssbake.pipeline.techniques.prt.forecast import check_budget, prt_forecast
from sssbake.pipeline.techniques.prt.stage import bake_prt
from sssbake.pipeline.techniques.technique import Budget

MARBLE = preset("marble")


def ball(subdivisions: int = 4, radius: float = 3.0) -> Surface:
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    x, f = np.asarray(s.vertices), np.asarray(s.faces)
    return Surface(x, f, area_weighted_normals(x, f), vertex_areas(x, f), (np.arange(len(x)),))


def test_forecast_holds_the_gather_and_q():
    s = ball()
    plan = scatter_plan(s.positions * 10.0, s.faces, s.normals, profile_for(MARBLE))
    few, many = prt_forecast(plan, 50), prt_forecast(plan, 200)
    op = plan.build()
    q = 3 * len(s.positions) * 200 * 4  # float32 q
    assert many.entries == op.nnz
    assert many.peak_bytes >= op.nbytes + q
    # q grows with the directions, the gather does not
    assert many.peak_bytes - few.peak_bytes >= 3 * len(s.positions) * 150 * 4
    assert many.seconds > 0 and few.seconds > 0  # timed: each forecast measures its own


def test_bake_within_budget_reports_its_forecast():
    s = ball(3)
    baked = bake_prt(s, 10.0, MARBLE, 50, 0.01, PRT_COMPRESS_DEFAULTS, Budget(8 * 2.0**30, 3600.0))
    f = baked.report["forecast"]
    assert f["entries"] == baked.report["gather"]["entries"]
    assert f["peak_bytes"] > baked.report["gather"]["operator_bytes"]


@pytest.mark.parametrize("budget, limit", [(Budget(memory_bytes=1e5), "--asset-memory"),
                                           (Budget(seconds=1e-6), "--asset-timeout")])
def test_over_budget_refuses_before_the_gather(budget, limit):
    s = ball()
    with pytest.raises(ValueError, match=f"prt: .* forecast to need .*{limit}") as e:
        bake_prt(s, 10.0, MARBLE, 200, 0.01, PRT_COMPRESS_DEFAULTS, budget)
    assert "\n" not in str(e.value)


def test_the_error_offers_the_knob_that_fits():
    s = ball()
    x, params = s.positions * 10.0, profile_for(MARBLE)
    plan = scatter_plan(x, s.faces, s.normals, params)
    need = prt_forecast(plan, 200)
    fewer = prt_forecast(plan, 100)
    # room for 100 directions, not for 200
    budget = Budget(memory_bytes=0.5 * (need.peak_bytes + fewer.peak_bytes))
    with pytest.raises(ValueError, match=r"--prt-directions 100 \(about"):
        check_budget(need, budget, plan, x, s.faces, s.normals, params)
    check_budget(need, Budget(memory_bytes=need.peak_bytes), plan, x, s.faces, s.normals, params)
    check_budget(need, None, plan, x, s.faces, s.normals, params)
