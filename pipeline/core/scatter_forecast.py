"""What a scatter operator will hold and cost, before it is built: the rows of an evenly spread
sample of its targets built for real (`ScatterPlan.matrices`), timed, and scaled to every target.

Vertices are in Morton order inside the plan, so runs of consecutive targets taken every k-th
run spread over the whole surface, and the sample's entries per target are the whole's; a run's
targets read much the same sources, as in the whole build, so the time per target is the whole's
too (the tests hold the forecast to the built operator). The clusters' moments (`ScatterOperator.apply`) cost per source, not per target: they
are timed whole.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.scatter_kernels import cluster_moments
from sssbake.pipeline.core.scatter_operator import ChannelRows, ScatterPlan, layout_bytes

#: Share of the targets built for the forecast.
SAMPLE = 0.02
#: Most consecutive targets (in Morton order) per run of the sample.
RUN = 64
#: Fewest runs.
RUNS = 64
#: At least this many targets (all of a smaller surface: the forecast is then exact).
MIN_SAMPLE = 2000


@dataclass(frozen=True)
class ScatterForecast:
    """Attributes
    ----------
    entries : int
        Stored values over all channels and matrices (`ScatterOperator.nnz`).
    operator_bytes : int
        The operator's matrices and index arrays (`ScatterOperator.nbytes`).
    build_peak_bytes : int
        The most the build holds at once: every matrix built so far plus the one being assembled
        twice (its chunks and its final arrays).
    build_seconds : float
        Building the entries (the plan's own time excluded).
    apply_seconds : float
        Per signal gathered (`ScatterOperator.apply`'s products and moments).
    sampled : int
        Targets built.
    """

    entries: int
    operator_bytes: int
    build_peak_bytes: int
    build_seconds: float
    apply_seconds: float
    sampled: int


def scatter_forecast(plan: ScatterPlan, fraction: float = SAMPLE) -> ScatterForecast:
    """Parameters
    ----------
    plan : ScatterPlan
    fraction : float
        Share of the targets to build, in (0, 1] (at least `MIN_SAMPLE` of them).
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"scatter forecast: fraction must be in (0, 1], got {fraction}")
    n = len(plan.positions)
    step = max(1, min(int(round(1.0 / fraction)), n // MIN_SAMPLE))
    # runs of consecutive targets, evenly spaced: neighbours share sources as in the whole build;
    # at least RUNS of them, so that the sample spreads over the surface
    run = max(1, min(RUN, n // (step * RUNS)))
    first = np.arange(0, n, run * step)
    rows = (first[:, None] + np.arange(run)).ravel()
    rows = rows[rows < n]
    scale = n / len(rows)
    t = time.perf_counter()
    near, levels = plan.matrices(rows)  # per target: the plan holds what the clusters cost
    build = (time.perf_counter() - t) * scale
    # Built coarsest level first, the near pairs last (`ScatterPlan.matrices`), each in the layout
    # its sample took: the choice is by the ratio of the union to the channels' entries, which
    # the sample's share of targets keeps.
    matrices = [f.matrix for f in levels[::-1]] + [near]
    entries = sum(m.nnz * scale for m in matrices)
    sizes = [layout_bytes(m.shared, n, int(round(len(m.indices) * scale)), m.width, m.dtype.itemsize)
             for m in matrices]
    held, peak = 0.0, 0.0
    for size in sizes:
        peak = max(peak, held + 2.0 * size)
        held += size
    operator = held + n * (8 + 3 * 8) + sum(f.starts.nbytes for f in levels)  # order, source_area, starts
    return ScatterForecast(int(round(entries)), int(operator), int(max(peak, operator)), build,
                           _apply_seconds(plan, near, levels, scale), len(rows))


def _apply_seconds(plan: ScatterPlan, near: ChannelRows, levels: list, scale: float) -> float:
    """Seconds per signal of `ScatterOperator.apply`, timed as it runs: a pass of `threads · block`
    signals, its per-source work (the signal in internal order, each level's cluster moments, the
    result clamped and put back in the caller's order) as it is, the sample's products
    (`ChannelRows.product`) scaled to every target and shared among the apply's threads."""
    n, width = len(plan.positions), plan.workers * plan.options.block
    dtype = near.dtype
    signal = np.random.default_rng(0).random((n, width))
    area = np.tile(plan.area, (3, 1))  # `source_area` before the energy limit: the same work
    moments = [np.empty((3 * len(f.starts), width), dtype) for f in levels]
    q, out = np.zeros((3 * n, width), dtype), np.empty((3, n, width), dtype)
    # the compiled kernels loaded (or compiled) before the clock starts
    cluster_moments(signal[:1].astype(dtype), area[:, :1], np.zeros(1, np.int64), np.empty((3, width), dtype))
    for m, x in zip([near, *(f.matrix for f in levels)], [q, *moments]):
        m.product(0, 0, x, q, False)
    t = time.perf_counter()
    e = signal[plan.order].astype(dtype)
    for f, m in zip(levels, moments):
        cluster_moments(e, area, f.starts, m)
    np.maximum(q, 0.0, out=q)
    out[:, plan.order] = q.reshape(3, n, width)
    whole = time.perf_counter() - t
    runs = []
    for _ in range(3):  # the median of three: the sample's products take a few milliseconds
        t = time.perf_counter()
        near.product(0, near.rows, e, q, False)
        for f, m in zip(levels, moments):
            f.matrix.product(0, near.rows, m, q, True)
        runs.append((time.perf_counter() - t) * scale)
    # the moments run a level per thread, the rest of the per-source work on one
    return (whole + float(np.median(runs)) / plan.workers) / width
