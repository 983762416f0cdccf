"""The scatter operator's plan and forecast: the plan builds the operator `scatter_operator`
builds, and the forecast from a sample of rows matches the built operator."""

import numpy as np
import pytest
import trimesh

from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.scatter_forecast import scatter_forecast
from sssbake.pipeline.core.scatter_operator import ScatterOptions, scatter_operator, scatter_plan
from sssbake.pipeline.core.surface import area_weighted_normals

MARBLE = profile_for(preset("marble"))


def blob(subdivisions: int, radius_mm: float = 30.0):
    """A bumpy sphere: curved everywhere, so the clusters' levels all hold entries."""
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    x = np.asarray(s.vertices)
    x = x * radius_mm * (1.0 + 0.15 * np.sin(5 * x[:, :1]) * np.cos(4 * x[:, 1:2]))
    f = np.asarray(s.faces)
    return x, f, area_weighted_normals(x, f)


def test_plan_builds_the_operator():
    x, f, n = blob(4)
    a = scatter_operator(x, f, n, MARBLE)
    b = scatter_plan(x, f, n, MARBLE).build()
    assert np.array_equal(a.order, b.order) and len(a.levels) == len(b.levels) > 0
    for u, v in [(a.near, b.near)] + [(p.matrix, q.matrix) for p, q in zip(a.levels, b.levels)]:
        assert np.array_equal(u.indptr, v.indptr) and np.array_equal(u.indices, v.indices)
        assert np.array_equal(u.data, v.data) and np.array_equal(u.within, v.within)
    assert np.allclose(a.source_area, b.source_area, rtol=1e-12)


def test_forecast_of_every_row_is_exact():
    x, f, n = blob(3)  # 642 vertices: fewer than the smallest sample, so every row is built
    plan = scatter_plan(x, f, n, MARBLE)
    forecast = scatter_forecast(plan)
    op = plan.build()
    assert forecast.sampled == len(x)
    assert forecast.entries == op.nnz
    assert forecast.operator_bytes == pytest.approx(op.nbytes, rel=1e-9)
    assert forecast.build_peak_bytes >= forecast.operator_bytes


def test_forecast_from_a_sample_matches_the_built_operator():
    x, f, n = blob(6)  # 40962 vertices: a 2 % sample of runs
    plan = scatter_plan(x, f, n, MARBLE, ScatterOptions(energy_dropped=0.05))
    forecast = scatter_forecast(plan)
    op = plan.build()
    assert forecast.sampled < len(x) / 10
    assert forecast.entries == pytest.approx(op.nnz, rel=0.05)
    assert forecast.operator_bytes == pytest.approx(op.nbytes, rel=0.05)
    assert forecast.build_seconds > 0 and forecast.apply_seconds > 0


def test_forecast_rejects_a_bad_fraction():
    x, f, n = blob(2)
    with pytest.raises(ValueError, match="fraction"):
        scatter_forecast(scatter_plan(x, f, n, MARBLE), fraction=0.0)


def test_plan_needs_the_hierarchy():
    x, f, n = blob(2)
    with pytest.raises(ValueError, match="hierarchy"):
        scatter_plan(x, f, n, MARBLE, ScatterOptions(hierarchy=False))
