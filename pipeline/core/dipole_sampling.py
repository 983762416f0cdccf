"""Radii drawn in proportion to the dipole's Rd(r)·r (Mertens et al. 2003, as DESIGN.md §4 restates
it): the screen technique's importance-sampled gather offsets.

Each source of the dipole (real at depth z_r, virtual at z_v) contributes to 2π ∫ Rd(r) r dr the
term z (1 + σ_tr d) e^(-σ_tr d) / d³ with d = sqrt(r² + z²); as r dr = d dd and
d/dd (-e^(-σ_tr d) / d) = (1 + σ_tr d) e^(-σ_tr d) / d², its mass within r is
e^(-σ_tr z) - (z / d) e^(-σ_tr d). So the real term is chosen with probability
e^(-σ_tr z_r) / (e^(-σ_tr z_r) + e^(-σ_tr z_v)), and within it, with u = d / z, the CDF is
1 - e^(-σ_tr z (u - 1)) / u: setting it to ξ gives

    g(u) = σ_tr z (u - 1) + ln u + ln(1 - ξ) = 0,   u >= 1,   r = z sqrt(u² - 1).

g is increasing and concave with g(1) = ln(1 - ξ) <= 0, so Newton's iterates from u = 1 stay left
of the root and rise to it monotonically (the tangent of a concave function lies above it): no
step can overshoot into u < 1 or diverge, whatever σ_tr z is.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.dipole import DipoleParams

#: Newton stops when a step changes u by less than this (relative).
TOLERANCE = 1e-13
#: Largest ξ accepted (ξ = 1 puts the radius at infinity).
XI_MAX = 1.0 - 1e-12
#: Newton steps allowed (σ_tr z = 0 at ξ = XI_MAX needs about 40).
MAX_STEPS = 200


def solve_u(xi: np.ndarray, sigma_z: np.ndarray) -> np.ndarray:
    """The root u >= 1 of σ_tr z (u - 1) + ln u + ln(1 - ξ) = 0.

    Parameters
    ----------
    xi : (...,) float64
        In [0, XI_MAX].
    sigma_z : (...,) float64
        σ_tr z >= 0 (broadcast with `xi`).

    Returns
    -------
    (...,) float64
    """
    xi, sz = np.broadcast_arrays(np.asarray(xi, dtype=np.float64), np.asarray(sigma_z, dtype=np.float64))
    if np.any(~((xi >= 0.0) & (xi <= XI_MAX))) or np.any(~(sz >= 0.0) | ~np.isfinite(sz)):
        raise ValueError("dipole sampling: need 0 <= ξ <= 1 - 1e-12 and finite σ_tr z >= 0")
    c = np.log1p(-xi)
    u = np.ones_like(xi)
    active = c < 0.0
    for _ in range(MAX_STEPS):
        if not np.any(active):
            return u
        ua = u[active]
        g = sz[active] * (ua - 1.0) + np.log(ua) + c[active]
        step = g / (sz[active] + 1.0 / ua)
        u[active] = ua - step  # g <= 0 left of the root, so u only grows
        active[active] = np.abs(step) > TOLERANCE * ua
    raise RuntimeError("dipole sampling: Newton did not converge")  # cannot happen for valid input


def sample_radii(xi: np.ndarray, params: DipoleParams, channel: int) -> np.ndarray:
    """Radii (mm) distributed as Rd(r)·r in one colour channel, one uniform number each.

    ξ below the real term's probability p picks the real source and ξ / p its radius, the rest the
    virtual one and (ξ - p) / (1 - p): one number does both, so stratified ξ stay stratified.

    Parameters
    ----------
    xi : (m,) float64
        In [0, 1).
    params : DipoleParams
    channel : int
        0, 1 or 2.

    Returns
    -------
    (m,) float64
    """
    xi = np.asarray(xi, dtype=np.float64)
    sigma = float(params.sigma_tr[channel])
    z_r, z_v = float(params.z_r[channel]), float(params.z_v[channel])
    # e^(-σ z_r) / (e^(-σ z_r) + e^(-σ z_v)), written so that neither exponential underflows
    p_real = 1.0 / (1.0 + np.exp(-sigma * (z_v - z_r)))
    real = xi < p_real
    within = np.where(real, xi / p_real, (xi - p_real) / max(1.0 - p_real, 1e-300))
    z = np.where(real, z_r, z_v)
    u = solve_u(np.clip(within, 0.0, XI_MAX), sigma * z)
    return z * np.sqrt(np.maximum(u * u - 1.0, 0.0))


def radius_cdf(r: np.ndarray, params: DipoleParams, channel: int) -> np.ndarray:
    """P(radius <= r) of `sample_radii`: the share of 2π ∫ Rd(s) s ds within r, in closed form."""
    sigma = float(params.sigma_tr[channel])
    r = np.asarray(r, dtype=np.float64)
    total, inside = 0.0, 0.0
    for z in (float(params.z_r[channel]), float(params.z_v[channel])):
        d = np.sqrt(r * r + z * z)
        total = total + np.exp(-sigma * z)
        inside = inside + np.exp(-sigma * z) - (z / d) * np.exp(-sigma * d)
    return inside / total
