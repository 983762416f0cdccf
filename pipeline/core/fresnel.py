"""Fresnel transmittance into a dielectric of relative index η, exact and Schlick's approximation."""

from __future__ import annotations

import numpy as np


def fresnel_transmittance(eta, cos_i) -> np.ndarray:
    """Exact unpolarised Fresnel transmittance F_t(η, ω) for light arriving from outside.

    Parameters
    ----------
    eta : float or (...,) float64, >= 1
    cos_i : (...,) float64
        Cosine between the incident direction and the surface normal; values <= 0 transmit nothing.

    Returns
    -------
    (...,) float64 in [0, 1]
    """
    eta = np.asarray(eta, dtype=np.float64)
    ci = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    sin_t2 = (1.0 - ci * ci) / (eta * eta)
    ct = np.sqrt(np.clip(1.0 - sin_t2, 0.0, 1.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (ci - eta * ct) / (ci + eta * ct)
        rp = (eta * ci - ct) / (eta * ci + ct)
    # At grazing incidence (ci = ct·η... = 0) both ratios are -1/+1: total reflection.
    rs = np.where(ci > 0.0, rs, 1.0)
    rp = np.where(ci > 0.0, rp, 1.0)
    return np.clip(1.0 - 0.5 * (rs * rs + rp * rp), 0.0, 1.0)


def schlick_transmittance(eta, cos_i) -> np.ndarray:
    """Schlick's approximation 1 - [F0 + (1 - F0)(1 - cos)^5], F0 = ((η-1)/(η+1))²."""
    eta = np.asarray(eta, dtype=np.float64)
    ci = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    f0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    return 1.0 - (f0 + (1.0 - f0) * (1.0 - ci) ** 5)
