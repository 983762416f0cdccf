"""The screen technique's per-material sample tables (Mertens et al. 2003): tangent-plane offsets
for the gather, their weights, and an Rd lookup table.

The gather estimates B(x) = ∫ Rd(|x - x'|) E(x') dA' from samples x_i = x + offset_i on the
tangent plane (projected onto the surface at runtime, at true distance r'_i):

    B ≈ Σ_i Rd(r'_i) E(x_i) w_i,   w_i = 1 / (N p_imp(x_i) + U p_uni(x_i))   (mm²),

the balance heuristic over four sample sets: N offsets importance-sampled as Rd·r
(`dipole_sampling`), a third per channel (one set of positions for all three, since the runtime
reads each position once; a single channel's samples served ketchup's blue, whose scattering is 8×
narrower than its red, with 22 % noise), stratified in ξ, and U offsets uniform over a disc of
`UNIFORM_SHARE` of the widest channel's R_d, which keep the estimate robust near the centre; all on
one golden-angle spiral. On a plane (r' = r) and under uniform light the estimate tends to R_d in
every channel.

The Rd table holds Rd at r = r_max t², t evenly spaced (denser where Rd is steep), r_max where the
furthest channel's R_d is `TABLE_REACH` complete; its size is the smallest power of two whose
linear interpolation stays within `ScreenSamplesOptions.table_error` of the value (relative, measured at
every midpoint where Rd is at least 1e-6 of its peak, beyond the radius holding `TABLE_INNER` of the
channel's R_d: the Monte Carlo profile's peak at r = 0, light scattered a few times within ~1/100 of
a mean free path, holds little light and no pixel resolves it, while it would hold the table to
resolution it never uses; the energy check covers it).
"""

from __future__ import annotations


import numpy as np

from sssbake.pipeline.core.profile import (
    Profile,
    diffuse_reflectance_profile,
    profile_for,
    profile_total,
    radius_holding,
)
from sssbake.pipeline.core.profile_sampling import sample_radii
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.techniques.screen.data import ScreenSamples, table_integral
from sssbake.pipeline.techniques.screen.options import SCREEN_DEFAULTS, ScreenSamplesOptions

#: The uniform disc holds this share of the driving channel's R_d.
UNIFORM_SHARE = 0.5
#: The table reaches where this share of the furthest channel's R_d is inside.
TABLE_REACH = 1.0 - 1e-4
#: A table must hold every channel's R_d to within this share (its integral, `table_integral`).
TABLE_ENERGY = 0.02
#: Share of each channel's R_d within which the table's pointwise error is not measured.
TABLE_INNER = 0.01
#: Table sizes tried (powers of two).
TABLE_SIZES = tuple(2**k for k in range(6, 15))
GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def screen_samples(material: Material, options: ScreenSamplesOptions = SCREEN_DEFAULTS) -> ScreenSamples:
    """The sample tables of one material (module docstring)."""
    options.check()
    params = profile_for(material)
    spread = radius_holding(params, 0.5)
    driver = int(np.argmax(spread))
    rng = np.random.default_rng(options.seed)
    n, u = options.samples, options.uniform
    # N split over the channels, the widest first: each channel gets offsets of its own density,
    # stratified in ξ
    counts = np.full(3, n // 3)
    counts[np.argsort(-spread)[: n % 3]] += 1
    radii = [sample_radii((np.arange(k) + rng.random(k)) / max(k, 1), params, c) for c, k in enumerate(counts)]
    uniform_radius = float(radius_holding(params, UNIFORM_SHARE)[driver])
    uniform_r = uniform_radius * np.sqrt((np.arange(u) + rng.random(u)) / max(u, 1))
    r = np.concatenate(radii + [uniform_r])
    angle = rng.random() * 2.0 * np.pi + GOLDEN_ANGLE * np.arange(len(r))
    offsets = np.column_stack([r * np.cos(angle), r * np.sin(angle)])
    # balance heuristic over the four sets: w = 1 / Σ_sets count · density
    total = profile_total(params)
    density = diffuse_reflectance_profile(r, params) / np.maximum(total, 1e-300)  # per unit area, per channel
    p_uni = np.where(r <= uniform_radius, 1.0 / (np.pi * uniform_radius**2), 0.0)
    weights = 1.0 / (density @ counts + u * p_uni)
    reach = float(radius_holding(params, TABLE_REACH).max())
    table, error = _table(params, reach, options.table_error)
    return ScreenSamples(offsets, weights, driver, uniform_radius, table, reach, error)


def _table(params: Profile, reach: float, bound: float) -> tuple[np.ndarray, float]:
    """The smallest table of `TABLE_SIZES` within `bound` that also holds each channel's R_d
    within `TABLE_ENERGY`, and its measured error (a channel far narrower than the table's reach
    can hide inside its first interval, where the pointwise test sees nothing relevant)."""
    total = profile_total(params)
    inner = radius_holding(params, TABLE_INNER)
    for size in TABLE_SIZES:
        t = np.linspace(0.0, 1.0, size)
        values = diffuse_reflectance_profile(reach * t * t, params).T
        mid = 0.5 * (t[1:] + t[:-1])
        exact = diffuse_reflectance_profile(reach * mid * mid, params).T
        linear = 0.5 * (values[:, 1:] + values[:, :-1])
        relevant = (exact >= 1e-6 * values[:, :1]) & (exact > 0) & (reach * mid * mid >= inner[:, None])
        error = float(np.max(np.abs(linear - exact)[relevant] / exact[relevant], initial=0.0))
        held = np.abs(table_integral(values, reach) - total) <= TABLE_ENERGY * total
        if error <= bound and np.all(held):
            return values, error
    narrowest = float(radius_holding(params, 0.5).min())
    raise ValueError(f"screen: the channels' profiles span too many scales for one Rd table (it reaches "
                     f"{reach:.3g} mm, the narrowest channel holds half its R_d within {narrowest:.3g} mm); "
                     f"no table up to {TABLE_SIZES[-1]} entries is within {bound:g}: raise --screen-table-error")
