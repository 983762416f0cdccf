"""Patro 2007's spectral subsurface normals (§3.2), with the sums as DESIGN.md restates them.

The normal field is projected on the manifold harmonics Φ (M-orthonormal, `manifold_harmonics`):
``η_k = Σ_j M_jj n_j φ_k(j)``; what the m harmonics cannot hold is the residual Δn = n - Φ η.
A Gaussian low-pass filter F(ω) = exp(-(ω s)² / 2) on the frequency ω = sqrt(λ) weighs each
coefficient; the residual, which occupies the band [ω_m, ω_M] above the last harmonic, is scaled
by the filter's mean there, γ = (1 / (ω_M - ω_m)) ∫ F dω, with ω_M the mesh's Nyquist frequency
π / h, h its mean edge length. (Not sqrt(λ_max): the operator's largest eigenvalue follows its
smallest cell, so γ collapses on irregular meshes and deletes millimetre detail:
benchmarks/README.md#spectral-normals-nyquist.)

    n'' = Φ (F(ω) η) + γ Δn, normalised.

The filter is the heat kernel: on a plane, F in frequency is a Gaussian blur of standard
deviation s in space, so s is a length (mm) that the material sets (`spectral_precompute`).
With F ≡ 1 (s = 0) the normals come back exactly, γ = 1 included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erf

from sssbake.pipeline.core.naive_normals import unit_or_original


@dataclass(frozen=True, eq=False)
class NormalSpectrum:
    """Attributes
    ----------
    values : (m,) float64
        Eigenvalues λ, 1/mm².
    nyquist : float
        ω_M = π / (mean edge length), 1/mm: the top of the residual's band.
    coefficients : (m, 3) float64
        η.
    residual : (n, 3) float64
        Δn = n - Φ η.
    basis : (n, m) float64
        Φ.
    normals : (n, 3) float64
        The input normals (the fallback where a filtered one cancels).
    """

    values: np.ndarray
    nyquist: float
    coefficients: np.ndarray
    residual: np.ndarray
    basis: np.ndarray
    normals: np.ndarray

    def filtered(self, width_mm: float) -> tuple[np.ndarray, float]:
        """(n'' (n, 3) unit, γ) for a filter of spatial standard deviation `width_mm` (>= 0)."""
        weight = low_pass(self.values, width_mm)
        gamma = band_mean(float(np.sqrt(self.values[-1])), self.nyquist, width_mm)
        raw = self.basis @ (weight[:, None] * self.coefficients) + gamma * self.residual
        return unit_or_original(raw, self.normals), gamma


def normal_spectrum(basis: np.ndarray, values: np.ndarray, nyquist: float, mass: np.ndarray,
                    normals: np.ndarray) -> NormalSpectrum:
    """Project unit `normals` (n, 3) on `basis` (n, m), M-orthonormal for the lumped `mass` (n,);
    `nyquist` is ω_M (1/mm)."""
    coefficients = basis.T @ (mass[:, None] * normals)
    residual = normals - basis @ coefficients
    return NormalSpectrum(values, float(nyquist), coefficients, residual, basis, normals)


def low_pass(values: np.ndarray, width_mm: float) -> np.ndarray:
    """F(sqrt(λ)) = exp(-λ s² / 2) for eigenvalues λ (1/mm²)."""
    return np.exp(-0.5 * np.maximum(values, 0.0) * width_mm * width_mm)


def band_mean(low: float, high: float, width_mm: float) -> float:
    """γ: the mean of F(ω) = exp(-(ω s)² / 2) over [low, high] (1/mm); F(low) when the band is empty."""
    if not high > low or width_mm <= 0.0:
        return float(np.exp(-0.5 * (low * width_mm) ** 2))
    k = width_mm / np.sqrt(2.0)
    return float(np.sqrt(np.pi) / (2.0 * k) * (erf(k * high) - erf(k * low)) / (high - low))
