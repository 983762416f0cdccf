"""The dipole diffusion model of Jensen et al. 2001 (equations as checked in DESIGN.md §3).

All functions are vectorised and float64. Lengths are in mm, coefficients in 1/mm. Per-channel
parameters broadcast against the leading shape of `r`: pass ``r[..., None]`` with (3,) channel
arrays to get (..., 3) results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sssbake.pipeline.core.materials import Material


def fresnel_diffuse_reflectance(eta) -> np.ndarray:
    """Internal diffuse Fresnel reflectance F_dr(η), the rational fit used by Jensen et al. 2001."""
    eta = np.asarray(eta, dtype=np.float64)
    return -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta


def boundary_a(eta) -> np.ndarray:
    """Boundary mismatch term A = (1 + F_dr) / (1 - F_dr)."""
    fdr = fresnel_diffuse_reflectance(eta)
    return (1.0 + fdr) / (1.0 - fdr)


@dataclass(frozen=True)
class DipoleParams:
    """Per-channel dipole constants derived from a material.

    Attributes
    ----------
    alpha_prime, sigma_tr, z_r, z_v : (3,) float64
        Reduced albedo, effective transport coefficient (1/mm), real and virtual source depths (mm).
    eta : float
    """

    alpha_prime: np.ndarray
    sigma_tr: np.ndarray
    z_r: np.ndarray
    z_v: np.ndarray
    eta: float

    @staticmethod
    def from_coefficients(sigma_s_prime, sigma_a, eta: float) -> "DipoleParams":
        s = np.asarray(sigma_s_prime, dtype=np.float64)
        a = np.asarray(sigma_a, dtype=np.float64)
        st = s + a
        z_r = 1.0 / st
        return DipoleParams(
            alpha_prime=s / st,
            sigma_tr=np.sqrt(3.0 * a * st),
            z_r=z_r,
            z_v=z_r * (1.0 + 4.0 * boundary_a(eta) / 3.0),
            eta=float(eta),
        )

    @staticmethod
    def from_material(m: Material) -> "DipoleParams":
        return DipoleParams.from_coefficients(m.sigma_s_prime, m.sigma_a, m.eta)


def diffuse_reflectance_profile(r, p: DipoleParams) -> np.ndarray:
    """Rd(r): diffuse reflectance per unit area at distance r (1/mm²).

    Parameters
    ----------
    r : (...,) float64, mm, >= 0
    p : DipoleParams

    Returns
    -------
    (..., 3) float64
    """
    r2 = np.square(np.asarray(r, dtype=np.float64))[..., None]
    out = np.zeros(r2.shape[:-1] + (3,))
    for z in (p.z_r, p.z_v):
        d = np.sqrt(r2 + z * z)
        sd = p.sigma_tr * d
        out += z * (1.0 + sd) * np.exp(-sd) / (d * d * d)
    return out * (p.alpha_prime / (4.0 * np.pi))


def profile_derivatives(r, p: DipoleParams, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rd, dRd/dr and d²Rd/dr² of channel c at r (mm), (...,) float64 each.

    With g(D) = (1 + σD) e^(-σD) / D³ and D² = r² + z²: g' = -e (σ²D² + 3σD + 3) / D⁴,
    g'' = e (σ³D³ + 5σ²D² + 12σD + 12) / D⁵, and dD/dr = r/D, d²D/dr² = z²/D³.
    """
    r = np.asarray(r, dtype=np.float64)
    s = p.sigma_tr[c]
    out = [np.zeros_like(r) for _ in range(3)]
    for z in (p.z_r[c], p.z_v[c]):
        d2 = r * r + z * z
        d = np.sqrt(d2)
        e = np.exp(-s * d)
        g1 = -e * (s * s * d2 + 3.0 * s * d + 3.0) / (d2 * d2)
        g2 = e * (s**3 * d2 * d + 5.0 * s * s * d2 + 12.0 * s * d + 12.0) / (d2 * d2 * d)
        out[0] += z * (1.0 + s * d) * e / (d2 * d)
        out[1] += z * g1 * r / d
        out[2] += z * (g2 * r * r / d2 + g1 * z * z / (d2 * d))
    k = p.alpha_prime[c] / (4.0 * np.pi)
    return k * out[0], k * out[1], k * out[2]


def _source_disc_term(a2, z, sigma_tr):
    """e^(-σ z) - (z/d) e^(-σ d) with d = sqrt(a² + z²), free of cancellation for small a."""
    d = np.sqrt(a2 + z * z)
    excess = a2 / (d + z)  # d - z, computed stably
    return np.exp(-sigma_tr * z) * -np.expm1(-np.log1p(excess / z) - sigma_tr * excess)


def disc_integral(a, p: DipoleParams) -> np.ndarray:
    """Exact 2π ∫_0^a Rd(r) r dr: the reflectance gathered from a disc of radius a around the point.

    Used for a vertex's own area (the self term), which a point sample would get badly wrong.

    Parameters
    ----------
    a : (...,) float64, mm, >= 0

    Returns
    -------
    (..., 3) float64, in [0, R_d]
    """
    a2 = np.square(np.asarray(a, dtype=np.float64))[..., None]
    total = _source_disc_term(a2, p.z_r, p.sigma_tr) + _source_disc_term(a2, p.z_v, p.sigma_tr)
    return 0.5 * p.alpha_prime * total


def total_diffuse_reflectance(alpha_prime, eta) -> np.ndarray:
    """Closed-form total diffuse reflectance R_d(α', η) = 2π ∫_0^∞ Rd(r) r dr."""
    alpha_prime = np.asarray(alpha_prime, dtype=np.float64)
    k = np.sqrt(3.0 * np.clip(1.0 - alpha_prime, 0.0, None))
    return 0.5 * alpha_prime * (1.0 + np.exp(-(4.0 / 3.0) * boundary_a(eta) * k)) * np.exp(-k)


def radius_for_energy(fraction_dropped: float, p: DipoleParams, r_max: float = 1e12) -> np.ndarray:
    """Smallest radius a (mm, per channel) with 2π∫_a^∞ Rd r dr <= fraction_dropped · R_d.

    The neighbourhood radius of a gather comes from this energy bound rather than from
    e^(-σ_tr r): without absorption the profile falls off only as 1/r³.
    """
    total = 0.5 * p.alpha_prime * (np.exp(-p.sigma_tr * p.z_r) + np.exp(-p.sigma_tr * p.z_v))
    target = (1.0 - fraction_dropped) * total
    lo = np.zeros(3)
    hi = np.full(3, float(r_max))
    for _ in range(200):  # bisection on a monotone function; 200 halvings reach float64 resolution
        mid = 0.5 * (lo + hi)
        enough = np.diagonal(disc_integral(mid, p)) >= target
        hi = np.where(enough, mid, hi)
        lo = np.where(enough, lo, mid)
    return hi


def radius_holding(params: DipoleParams, energy: float) -> np.ndarray:
    """(3,) radius (mm) within which the disc integral reaches `energy` (in (0, 1)) of R_d, per
    channel (bisection, doubling from z_v until the disc holds it)."""
    total = total_diffuse_reflectance(params.alpha_prime, params.eta)

    def reached(r: np.ndarray) -> np.ndarray:  # channel c's disc integral at radius r[c]
        return np.diagonal(disc_integral(r, params)) >= energy * total

    lo, hi = np.zeros(3), np.maximum(params.z_v, 1e-12)
    while not np.all(reached(hi)) and hi.max() < 1e15:
        hi = np.where(reached(hi), hi, 2.0 * hi)
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        short = ~reached(mid)
        lo, hi = np.where(short, mid, lo), np.where(short, hi, mid)
    return hi
