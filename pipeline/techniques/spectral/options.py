"""spectral: its bake options (`BakeOptions`' ``spectral_*`` fields, TOML keys and ``--spectral-*`` flags)."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.core.ranges import LENGTH_MAX_MM, Range
from sssbake.pipeline.techniques.option import option
from sssbake.pipeline.techniques.spectral.precompute import SPECTRAL_DEFAULTS, SpectralPrecomputeOptions

_D = SPECTRAL_DEFAULTS
#: The filter's width, mm: it squares it (exp(-λ s² / 2), `normals.low_pass`), which overflowed at
#: 1e300; a width past `LENGTH_MAX_MM` (the profile's own reach) averages every object flat anyway.
WIDTH_MM = Range(0.0, LENGTH_MAX_MM, "the filter squares its width", "mm")


@dataclass(frozen=True)
class SpectralOptions:
    """Attributes
    ----------
    eigenpairs, width_mm
        The precompute (`precompute.SpectralPrecomputeOptions`).
    variant : bool
        Also write ``<stem>.sss_normals.glb``, whose standard NORMAL is the spectral subsurface
        normal (a stock viewer shows the effect).
    basis : bool
        Also export the spectrum (coefficients, eigenvalues, residual, basis) so that a runtime
        can filter again.
    """

    eigenpairs: int = option(_D.eigenpairs, "spectral: harmonics the normals are filtered in (default {default})")
    width_mm: float | None = option(_D.width_mm, "spectral: the filter's spatial standard deviation "
                                                 "(default: from the material)", range=WIDTH_MM)
    variant: bool = option(False, "spectral: also write STEM.sss_normals.glb, its NORMAL the spectral normal "
                                  "(for stock viewers)", flag=True)
    basis: bool = option(False, "spectral: also export the spectrum (coefficients, eigenvalues, residual, basis) to "
                                "filter again at runtime", flag=True)

    def precompute(self) -> SpectralPrecomputeOptions:
        return SpectralPrecomputeOptions(self.eigenpairs, self.width_mm)

    def check(self) -> None:
        """Raise ValueError with a one-line reason for an impossible setting."""
        self.precompute().check()
