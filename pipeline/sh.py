"""Real spherical harmonics (Sloan 2002 normalisation, as Hao & Varshney 2004 print it) and their
least-squares fit to values sampled at a direction set.

Index i = l² + l + m for 0 <= l < order, -l <= m <= l; order n has n² functions.
"""

from __future__ import annotations

from math import factorial, pi, sqrt

import numpy as np

MAX_ORDER = 8


def sh_count(order: int) -> int:
    return order * order


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


def sh_fit_matrix(directions: np.ndarray, order: int) -> np.ndarray:
    """(order², K) least-squares projection from values at `directions` (K, 3) to coefficients.

    Least squares rather than 4π/K quadrature: Fibonacci points are not an exact quadrature, and
    the fit is exact for band-limited signals whenever K >= order².
    """
    if len(directions) < order * order:
        raise ValueError(f"sh: {len(directions)} directions cannot determine {order * order} coefficients")
    return np.linalg.pinv(sh_basis(directions, order))


def _double_factorial(n: int) -> float:
    return float(np.prod(np.arange(n, 0, -2))) if n > 0 else 1.0
