"""The report's reference at a fraction of the exact sum's cost: the clustered sum at every vertex
(`reference.reference_scattering` with ``clustered=True``: far sources through float64 clusters at
separation 3), checked against the exact pair sum at a random sample of vertices.

The exact sum costs O(n · sources within the energy radius): on a 15k-vertex armadillo of potato
(10k sources within the radius of each vertex) it took 234 s, three times its whole bake
(benchmarks/README.md#report-verification-cost). The clustered sum takes seconds. The exact sum
is

    q_c(o) = Σ_i W_c(o, i) · s_ic · E_i ,

over every source i within the channel's energy radius, W the near field's cell integrals
(`NearField.weights`), E the incident signal (`reference.incident_signal`) and s_i the source's
energy scale, min(1, R_d / its outgoing fraction Σ_o ΔA_o W_c(o, i) / ΔA_i) (no source sends out
more than R_d; on the armadillo nearly every source is scaled, by up to 0.3). Its pair sum at k
receivers drawn uniformly without replacement costs k/n of the whole, but the scales need every
receiver of each source. So the check has two samples, each of half the pair budget:

- at k receivers, the exact pair sum with the clustered operator's scales (`exact`): the clusters'
  error in the gather;
- at m sources drawn among the lit ones, the exact outgoing fraction, hence the exact scale: the
  largest relative difference R from the clustered scale (`scale_error`, per channel).

Since the exact reference is Σ W E s_clu (1 + r_i) with |r_i| <= R, it is within R · exact of
`exact`, and the clustered reference within |clustered - exact| + R · exact of it at each sampled
receiver (R a sample's largest, not a proof). `check_figures` states that in the image's units,
with a bootstrap interval over the receivers."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.reference import Light, back_gain, incident_signal
from sssbake.pipeline.core.scatter_operator import ScatterOptions, scatter_plan
from sssbake.pipeline.core.surface import Surface

#: The reference's energy truncation (`reference.reference_scattering`'s default).
ENERGY_DROPPED = 1e-4
#: Cluster separation of the clustered reference (`reference.reference_scattering`'s).
SEPARATION = 3
#: Vertex pairs the exact check may evaluate (`checked_reference`'s `pairs`): 1-3 us each on this
#: 2-core machine (the near field's disc integrals), so 2-5 s; on the armadillo 203 receivers and 77
#: sources, the bound's 95 % interval +-11 % of it (benchmarks/README.md#report-verification-cost).
CHECK_PAIRS = 1_500_000
#: Pairs evaluated at once (`reference.PAIRS_PER_CHUNK`'s ~100 bytes each).
PAIRS_PER_CHUNK = 1_000_000
#: Fewest and most vertices the check samples (a mesh with fewer is checked at every vertex).
CHECK_MIN, CHECK_MAX = 64, 2000
#: Bootstrap resamples of the check's confidence interval.
BOOTSTRAP = 2000


@dataclass(frozen=True)
class ReferenceCheck:
    """The clustered reference against the exact sum at sampled vertices of one surface.

    Attributes
    ----------
    vertices : (k,) int64
        The sampled (welded) vertices.
    clustered : (3, k) float64
        The clustered reference there (after the back gain).
    exact : (3, k) float64
        The exact pair sum there with the clustered sums' energy scales.
    scale_error : (3,) float64
        Per channel, the largest relative difference between a sampled source's exact energy
        scale and the clustered one: the exact reference is within ``scale_error · exact`` of
        `exact`.
    sources : int
        The sources sampled for `scale_error`.
    of : int
        The surface's vertices.
    seconds : float
        The exact sums of the check.
    """

    vertices: np.ndarray
    clustered: np.ndarray
    exact: np.ndarray
    scale_error: np.ndarray
    sources: int
    of: int
    seconds: float


def checked_reference(surface: Surface, mm_per_unit: float, material: Material, light: Light,
                      pairs: int = CHECK_PAIRS, seed: int = 0) -> tuple[np.ndarray, ReferenceCheck]:
    """The clustered reference at every vertex of `surface` and its check against the exact sum.

    Parameters
    ----------
    surface : Surface
        Welded, file units.
    mm_per_unit : float
    material : Material
    light : Light
        In the surface's frame.
    pairs : int
        Budget of (target, source) pairs for the exact sums: the sample is as large as it allows,
        between `CHECK_MIN` and `CHECK_MAX` vertices.
    seed : int
        Of the sample (the same mesh and light draw the same vertices).

    Returns
    -------
    q : (3, n) float64
        Scattered radiance at every vertex (before the view Fresnel), as
        ``reference_scattering(..., clustered=True)``.
    check : ReferenceCheck
    """
    params = profile_for(material)
    plan = scatter_plan(surface.positions * mm_per_unit, surface.faces, surface.normals, params,
                        ScatterOptions(energy_dropped=ENERGY_DROPPED, separation=SEPARATION, float32=False))
    operator = plan.build()
    signal = incident_signal(surface, mm_per_unit, material, light)
    gain = back_gain(surface, material, light)
    q = operator.apply(signal[:, None])[:, :, 0] * gain

    t = time.perf_counter()
    n = len(signal)
    field = plan.builder.field  # internal (Morton) order, as `plan.area` and the operator's source_area
    x, area, radius = field.positions, plan.area, plan.radius_mm
    inverse = np.empty(n, dtype=np.int64)
    inverse[plan.order] = np.arange(n)
    e = signal[plan.order]
    scale = np.divide(operator.source_area, area, out=np.ones((3, n)), where=area > 0)
    active = np.flatnonzero(e * area > 0)
    rng = np.random.default_rng(seed)
    # half the pairs for the receivers' sums, half for the sources' outgoing sums (their energy scales)
    sample = np.sort(rng.permutation(n)[:_sample_size(n, x, x[active], radius, pairs // 2)])
    exact = np.zeros((3, len(sample)))
    for rows, cols, w in _pairs(field, inverse[sample], active, radius, receive=True):
        for c in range(3):
            exact[c] += np.bincount(rows, weights=w[:, c] * e[cols] * scale[c, cols], minlength=len(sample))
    sources = np.sort(rng.permutation(active)[:_sample_size(len(active), x[active], x, radius, pairs // 2)])
    outgoing = np.zeros((3, len(sources)))
    for rows, cols, w in _pairs(field, sources, np.arange(n), radius, receive=False):
        outgoing += np.stack([np.bincount(rows, weights=w[:, c] * area[cols], minlength=len(sources))
                              for c in range(3)])
    # the exact sum's scale (`reference._scattering`: sources over (1 - 1e-6) R_d scaled down as a whole)
    limit = (1.0 - 1e-6) * plan.total[:, None]
    fraction = outgoing / np.where(area[sources] > 0, area[sources], 1.0)
    exact_scale = np.where(fraction > limit, limit / np.maximum(fraction, 1e-300), 1.0)
    scale_error = (np.abs(exact_scale / scale[:, sources] - 1.0).max(axis=1) if len(sources) else np.zeros(3))
    exact = np.maximum(exact, 0.0) * gain[:, sample]
    return q, ReferenceCheck(sample, q[:, sample], exact, scale_error, len(sources), n, time.perf_counter() - t)


def _pairs(field, centres: np.ndarray, among: np.ndarray, radius: np.ndarray, receive: bool):
    """Every (centre, vertex of `among`) pair within the largest of `radius` (3,), in runs of about
    `PAIRS_PER_CHUNK` pairs: yields (rows (p,) indices into `centres`, cols (p,) the vertices of
    `among`, w (p, 3) float64 the cell integrals W_c(o, i) = ∫_{cell_i} Rd_c(|y - x_o|) dy, 0
    beyond the channel's radius), the centre the receiver o when `receive`, else the source i."""
    if len(centres) == 0 or len(among) == 0:
        return
    x = field.positions
    lists = cKDTree(x[among]).query_ball_point(x[centres], float(radius.max()))
    counts = np.fromiter((len(v) for v in lists), dtype=np.int64, count=len(lists))
    ends = np.cumsum(counts)
    start = 0
    while start < len(centres):
        stop = max(start + 1, int(np.searchsorted(ends, ends[start] - counts[start] + PAIRS_PER_CHUNK, "right")))
        rows = np.repeat(np.arange(start, stop), counts[start:stop])
        if len(rows):
            cols = among[np.concatenate([np.asarray(v, dtype=np.int64) for v in lists[start:stop]])]
            o, i = (centres[rows], cols) if receive else (cols, centres[rows])
            w = field.weights(o, i)
            d = np.linalg.norm(x[o] - x[i], axis=1)
            yield rows, cols, np.where(d[:, None] <= radius[None, :], w, 0.0)
        start = stop


def _sample_size(n: int, centres: np.ndarray, among: np.ndarray, radius: np.ndarray, pairs: int) -> int:
    """How many of the `n` points `centres` (n, 3) the check can pair with the points `among` (m, 3)
    within `radius`'s largest inside `pairs` (from 200 probes), between `CHECK_MIN` and `CHECK_MAX`, at most `n`."""
    if len(among) == 0:
        return min(n, CHECK_MAX)
    probe = centres[:: max(1, n // 200)]
    per_centre = float(np.mean(cKDTree(among).query_ball_point(probe, float(radius.max()), return_length=True)))
    return int(min(n, CHECK_MAX, max(CHECK_MIN, pairs // max(per_centre, 1.0))))


def check_figures(checks: list[ReferenceCheck], exposure: float, seed: int = 0) -> dict:
    """What the report says of the checks of one comparison's surfaces, at its `exposure` (the
    image's units: a shift of the reference by d moves an image RMSE by at most |d| · exposure;
    the view Fresnel factor the renderer applies is below 1, so less).

    Per sampled vertex the clustered reference is within |clustered - exact| + scale_error · exact
    of the exact reference (`ReferenceCheck`): that bound, times `exposure` and at most 1.

    Returns
    -------
    dict
        ``vertices`` (sampled, over all surfaces), ``of`` (their vertices), ``rms`` (RMS over the
        sampled vertices and channels of the bound: how far the RMSE figures can move from the
        exact reference's), ``rms_ci95`` ([lo, hi], percentile bootstrap over the sampled
        vertices), ``relative`` (the same RMS before the exposure over the exact reference's),
        ``max`` (largest bound), ``scale_error`` (largest over channels and surfaces), ``sources``
        (sampled for it) and ``seconds``.
    """
    clustered = np.concatenate([c.clustered for c in checks], axis=1)
    exact = np.concatenate([c.exact for c in checks], axis=1)
    bound = np.abs(clustered - exact) + np.concatenate([c.scale_error[:, None] * c.exact for c in checks], axis=1)
    d = np.minimum(bound * exposure, 1.0) ** 2
    per_vertex = d.mean(axis=0)  # (k,)
    k = len(per_vertex)
    common = {"of": int(sum(c.of for c in checks)), "sources": int(sum(c.sources for c in checks)),
              "scale_error": float(max(c.scale_error.max() for c in checks)),
              "seconds": float(sum(c.seconds for c in checks))}
    if k == 0:
        return {"vertices": 0, "rms": 0.0, "rms_ci95": [0.0, 0.0], "relative": 0.0, "max": 0.0, **common}
    draws = np.random.default_rng(seed).integers(0, k, size=(BOOTSTRAP, k))
    boot = np.sqrt(per_vertex[draws].mean(axis=1))
    size = np.sqrt(np.mean(exact**2))
    rms = float(np.sqrt(per_vertex.mean()))
    return {"vertices": int(k), "rms": rms,
            "rms_ci95": [float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))],
            "relative": float(np.sqrt(np.mean(bound**2)) / size) if size > 0 else 0.0,
            "max": float(np.sqrt(d.max())), **common}
