"""Real spherical harmonics (Sloan 2002 normalisation, as Hao & Varshney 2004 print it) and their
fit to values sampled at a direction set.

Index i = l² + l + m for 0 <= l < order, -l <= m <= l; order n has n² functions.

Least squares is the default projection: never worse than 4π/K quadrature, and lower at high
orders and few directions (benchmarks/README.md#sh-projection), since quadrature is not exact on
Fibonacci points and least squares is exact for any band-limited signal once K >= n².
"""

from __future__ import annotations

from math import factorial, pi, sqrt

import numpy as np

MAX_ORDER = 8
METHODS = ("lsq", "quadrature")


def sh_basis(omega: np.ndarray, order: int) -> np.ndarray:
    """Real SH basis functions at unit directions.

    Parameters
    ----------
    omega : (m, 3) float64
        Unit directions (x, y, z) = (sinθ cosφ, sinθ sinφ, cosθ).
    order : int
        0 .. MAX_ORDER.

    Returns
    -------
    (m, order²) float64
    """
    if not 0 <= order <= MAX_ORDER:
        raise ValueError(f"sh: order must be in [0, {MAX_ORDER}], got {order}")
    omega = np.atleast_2d(np.asarray(omega, dtype=np.float64))
    if omega.ndim != 2 or omega.shape[1] != 3 or not np.all(np.isfinite(omega)):
        raise ValueError(f"sh: directions must be finite (m, 3) unit vectors, got shape {omega.shape}")
    x, y, z = omega[:, 0], omega[:, 1], omega[:, 2]
    out = np.zeros((len(omega), order * order))
    # (x + iy)^m = sin^m θ e^{imφ}: the sin^m θ of P_l^m without dividing by sin θ.
    power = np.ones(len(omega), dtype=np.complex128)
    for m in range(order):
        # Q_l^m = P_l^m / sin^m θ, a polynomial in z (Condon-Shortley phase included).
        q_prev = np.zeros_like(z)
        q = np.full_like(z, (-1.0) ** m * _double_factorial(2 * m - 1))
        for l in range(m, order):
            if l > m:
                q, q_prev = ((2 * l - 1) * z * q - (l + m - 1) * q_prev) / (l - m), q
            k = sqrt((2 * l + 1) / (4 * pi) * factorial(l - m) / factorial(l + m))
            if m == 0:
                out[:, l * l + l] = k * q
            else:
                out[:, l * l + l + m] = sqrt(2.0) * k * q * power.real
                out[:, l * l + l - m] = sqrt(2.0) * k * q * power.imag
        power = power * (x + 1j * y)
    return out


def sh_fit_matrix(directions: np.ndarray, order: int, method: str = "lsq") -> np.ndarray:
    """(order², K) linear map from values at `directions` (K, 3) to SH coefficients.

    ``"lsq"``: the least-squares fit (pseudo-inverse of the basis at the directions);
    ``"quadrature"``: 4π/K Σ_j f(ω_j) y_i(ω_j), equal-weight quadrature.
    """
    if method not in METHODS:
        raise ValueError(f"sh: method must be one of {METHODS}, got {method!r}")
    directions = np.asarray(directions, dtype=np.float64)
    if directions.ndim != 2 or directions.shape[1] != 3:
        raise ValueError(f"sh: directions must be (K, 3), got {directions.shape}")
    if len(directions) < order * order:
        raise ValueError(f"sh: {len(directions)} directions cannot determine {order * order} coefficients; "
                         "lower the order or use more directions")
    basis = sh_basis(directions, order)
    if method == "quadrature":
        return basis.T * (4.0 * pi / len(directions))
    return np.linalg.pinv(basis)


def sh_project(values: np.ndarray, directions, order: int, method: str = "lsq") -> np.ndarray:
    """SH coefficients of functions sampled at a direction set.

    Parameters
    ----------
    values : (..., K) float64
        Samples, last axis over the directions.
    directions : DirectionSet or (K, 3) float64
    order : int
    method : str
        ``"lsq"`` (default) or ``"quadrature"`` (see `sh_fit_matrix`).

    Returns
    -------
    (..., order²) float64
    """
    directions = getattr(directions, "directions", directions)
    values = np.asarray(values, dtype=np.float64)
    if values.shape[-1:] != (len(directions),):
        raise ValueError(f"sh: values must end with an axis of {len(directions)} directions, got {values.shape}")
    return values @ sh_fit_matrix(directions, order, method).T


def _double_factorial(n: int) -> float:
    return float(np.prod(np.arange(n, 0, -2))) if n > 0 else 1.0
