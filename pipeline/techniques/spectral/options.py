"""spectral: its bake options (`BakeOptions`' ``spectral_*`` fields, TOML keys and ``--spectral-*`` flags)
and the precompute's: no numpy here, so that ``sssbake bake --help`` imports none."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.core.ranges import LENGTH_MAX_MM, Range
from sssbake.pipeline.techniques.option import option

#: The filter's width, mm: it squares it (exp(-λ s² / 2), `normals.low_pass`), which overflowed at
#: 1e300; a width past `LENGTH_MAX_MM` (the profile's own reach) averages every object flat anyway.
WIDTH_MM = Range(0.0, LENGTH_MAX_MM, "the filter squares its width", "mm")


@dataclass(frozen=True)
class SpectralPrecomputeOptions:
    """Attributes
    ----------
    eigenpairs : int
        m, the harmonics the normals are filtered in (fewer on smaller meshes).
    width_mm : float or None
        The filter's spatial standard deviation s; None: from the material (`precompute`'s module docstring).
    """

    eigenpairs: int = 300
    width_mm: float | None = None

    def check(self) -> None:
        if not (isinstance(self.eigenpairs, int) and 1 <= self.eigenpairs <= 5000):
            raise ValueError(f"spectral: eigenpairs must be a whole number in [1, 5000], got {self.eigenpairs!r}")
        value = self.width_mm
        if value is not None and not (isinstance(value, (int, float)) and 0 <= value < float("inf")):
            raise ValueError(f"spectral: width_mm must be a finite number >= 0 or None, got {value!r}")


SPECTRAL_DEFAULTS = SpectralPrecomputeOptions()
_D = SPECTRAL_DEFAULTS


@dataclass(frozen=True)
class SpectralOptions:
    """Attributes
    ----------
    eigenpairs, width_mm
        The precompute (`SpectralPrecomputeOptions`).
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
