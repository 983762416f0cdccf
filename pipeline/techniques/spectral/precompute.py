"""The spectral technique's precompute (Patro 2007): subsurface normals by low-pass filtering in
the manifold harmonics basis (`spectral_normals`), with every length from the material at the
asset's scale. Patro's naive normals (neighbour weighting, `naive_normals`) are the comparison
verify and tradeoff draw: their parameters are here, the bake does not compute them.

One normal field serves all three colour channels, so the channels' scattering lengths are
combined, each weighted by its share of the total diffuse reflectance R_d (what it contributes
to the picture):

- filter width s: a 2-D Gaussian of standard deviation s holds half its mass within
  s sqrt(2 ln 2); s is set so that this median radius is the dipole's (the radius r₅₀ where the
  disc integral reaches R_d / 2, finite even without absorption, unlike the second moment);
- naive σ_tr: the channels' σ_tr; naive radius: where the disc integral reaches `NAIVE_ENERGY`
  of R_d (an energy bound, so σ_tr → 0 still gives a finite neighbourhood); naive α: `NAIVE_ALPHA`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from sssbake.pipeline.core.profile import Profile, profile_for, profile_total, radius_holding
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.techniques.spectral.laplacian import cotangent_laplacian
from sssbake.pipeline.techniques.spectral.manifold_harmonics import manifold_harmonics
from sssbake.pipeline.techniques.spectral.normals import NormalSpectrum, normal_spectrum
from sssbake.pipeline.techniques.spectral.options import SPECTRAL_DEFAULTS, SpectralPrecomputeOptions

#: Share of R_d within the naive neighbourhood's radius.
NAIVE_ENERGY = 0.95
#: Naive normals: the weight of a vertex's own normal (Patro: below 1).
NAIVE_ALPHA = 0.5


@dataclass(frozen=True, eq=False)
class SpectralPrecompute:
    """Attributes
    ----------
    normals : (n, 3) float64
        The spectral subsurface normals of the surface's vertices, unit.
    spectrum : NormalSpectrum
        Coefficients, residual and basis, to filter again (`NormalSpectrum.filtered`).
    width_mm, gamma : float
        The filter width and the residual's factor.
    stats, seconds : dict
    """

    normals: np.ndarray
    spectrum: NormalSpectrum
    width_mm: float
    gamma: float
    stats: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)


def precompute_spectral(surface: Surface, mm_per_unit: float, material: Material,
                        options: SpectralPrecomputeOptions = SPECTRAL_DEFAULTS) -> SpectralPrecompute:
    """Parameters
    ----------
    surface : Surface
        A welded surface (positions in mesh units, unit normals).
    mm_per_unit : float
    material : Material
    options : SpectralPrecomputeOptions
    """
    options.check()
    seconds = {}
    params = profile_for(material)
    # a 2-D Gaussian of standard deviation s holds half its mass within s sqrt(2 ln 2)
    width = float(options.width_mm if options.width_mm is not None
                  else channel_weights(params) @ radius_holding(params, 0.5) / np.sqrt(2.0 * np.log(2.0)))
    x = surface.positions * mm_per_unit
    t = time.perf_counter()
    laplacian = cotangent_laplacian(x, surface.faces)
    seconds["laplacian"] = time.perf_counter() - t
    harmonics = manifold_harmonics(laplacian, options.eigenpairs)
    seconds["eigensolve"] = harmonics.seconds["eigensolve"]
    t = time.perf_counter()
    spectrum = normal_spectrum(harmonics.vectors, harmonics.values, nyquist_frequency(x, surface.faces), laplacian.mass,
                               surface.normals)
    normals, gamma = spectrum.filtered(width)
    seconds["filter"] = time.perf_counter() - t
    cos = np.einsum("ij,ij->i", normals, surface.normals)
    stats = {"vertices": len(x), "eigenpairs": len(harmonics.values), "bands": harmonics.bands,
             "slivers": laplacian.slivers, "widthMm": width, "gamma": gamma,
             "lowestFrequency": float(np.sqrt(harmonics.values[-1])),
             "nyquistFrequency": spectrum.nyquist,
             # the highest frequency the basis holds, against the filter's: how much the cut matters
             "filterAtCutoff": float(np.exp(-0.5 * harmonics.values[-1] * width * width)),
             "meanTiltDegrees": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).mean())}
    return SpectralPrecompute(normals, spectrum, width, gamma, stats, seconds)


def naive_parameters(material: Material) -> tuple[float, float]:
    """The naive normals' σ_tr (1/mm) and neighbourhood radius (mm) from the material (module docstring)."""
    params = profile_for(material)
    share = channel_weights(params)
    return float(share @ params.sigma_tr), float(share @ radius_holding(params, NAIVE_ENERGY))


def nyquist_frequency(positions_mm: np.ndarray, faces: np.ndarray) -> float:
    """π / h (1/mm), h the mean edge length of the triangles (each edge counted once per triangle)."""
    x = positions_mm[faces]
    edges = np.linalg.norm(x - np.roll(x, 1, axis=1), axis=2)
    mean = float(edges.mean()) if edges.size else 0.0
    return np.pi / mean if mean > 0 else float("inf")


def channel_weights(params: Profile) -> np.ndarray:
    """(3,) each channel's share of R_d (equal shares when R_d is 0 in every channel)."""
    total = profile_total(params)
    return total / total.sum() if total.sum() > 0 else np.full(3, 1.0 / 3.0)


