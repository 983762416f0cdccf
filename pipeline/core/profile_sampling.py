"""Radii drawn in proportion to the profile's Rd(r)·r (Mertens et al. 2003's sampling of the
dipole, as DESIGN.md §4 restates it, extended to every pole of `profile.Profile`): the screen
technique's importance-sampled gather offsets.

Each pole k (weight w, depth z, decay σ) contributes to 2π ∫ Rd(r) r dr the term
(w/2) z (1 + σ d) e^(-σ d) / d³ · r dr with d = sqrt(r² + z²); as r dr = d dd and
d/dd (-e^(-σ d) / d) = (1 + σ d) e^(-σ d) / d², its mass within r is
(w/2) [e^(-σ z) - (z / d) e^(-σ d)]. So pole k is chosen with probability w_k e^(-σ_k z_k) / Σ_j
w_j e^(-σ_j z_j) (Mertens' choice between the real and the virtual source, for two poles), and
within it, with u = d / z, the CDF is 1 - e^(-σ z (u - 1)) / u: setting it to ξ gives

    g(u) = σ_tr z (u - 1) + ln u + ln(1 - ξ) = 0,   u >= 1,   r = z sqrt(u² - 1).

g is increasing and concave with g(1) = ln(1 - ξ) <= 0, so Newton's iterates from u = 1 stay left
of the root and rise to it monotonically (the tangent of a concave function lies above it): no
step can overshoot into u < 1 or diverge, whatever σ_tr z is.
"""

from __future__ import annotations

import numpy as np

from sssbake.pipeline.core.profile import Profile, pole_disc_term

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
        raise ValueError("profile sampling: need 0 <= ξ <= 1 - 1e-12 and finite σ_tr z >= 0")
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
    raise RuntimeError("profile sampling: Newton did not converge")  # cannot happen for valid input


def _pole_shares(params: Profile, channel: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z, σ, cumulative share, share) of channel `channel`'s weighted poles (where nothing leaves,
    every pole alike: the radii then weigh nothing)."""
    w, z, sigma = params.channel(channel)
    if len(w) == 0:
        w, z, sigma = np.ones(len(params.depth)), params.depth[:, channel], params.sigma[:, channel]
    mass = w * np.exp(-sigma * z)
    share = mass / mass.sum()
    return z, sigma, np.cumsum(share), share


def sample_radii(xi: np.ndarray, params: Profile, channel: int) -> np.ndarray:
    """Radii (mm) distributed as Rd(r)·r in one colour channel, one uniform number each.

    ξ in pole k's slice [P_(k-1), P_k) of the cumulative shares picks that pole and
    (ξ - P_(k-1)) / p_k its radius: one number does both, so stratified ξ stay stratified.

    Parameters
    ----------
    xi : (m,) float64
        In [0, 1).
    params : Profile
    channel : int
        0, 1 or 2.

    Returns
    -------
    (m,) float64
    """
    xi = np.asarray(xi, dtype=np.float64)
    z, sigma, upper, share = _pole_shares(params, channel)
    pole = np.minimum(np.searchsorted(upper, xi, side="right"), len(z) - 1)
    within = (xi - (upper[pole] - share[pole])) / np.maximum(share[pole], 1e-300)
    u = solve_u(np.clip(within, 0.0, XI_MAX), sigma[pole] * z[pole])
    return z[pole] * np.sqrt(np.maximum(u * u - 1.0, 0.0))


def radius_cdf(r: np.ndarray, params: Profile, channel: int) -> np.ndarray:
    """P(radius <= r) of `sample_radii`: the share of 2π ∫ Rd(s) s ds within r, in closed form."""
    z, sigma, _, share = _pole_shares(params, channel)
    r2 = np.square(np.asarray(r, dtype=np.float64))[..., None]
    return np.sum(share * pole_disc_term(r2, z, sigma) / np.exp(-sigma * z), axis=-1)
