"""spectral: what `registry` lists before importing the technique (`entry.TechniqueEntry`): its name,
options; its tradeoff sweeps are fixed (`tradeoff.EIGENPAIRS`, `tradeoff.WIDTH_FACTORS`,
`tradeoff.ALPHAS`): no flags of its own."""

from __future__ import annotations

from sssbake.pipeline.techniques.entry import TechniqueEntry
from sssbake.pipeline.techniques.spectral.options import SpectralOptions


class SpectralEntry(TechniqueEntry):
    name = "spectral"
    options_type = SpectralOptions
    implementation = "sssbake.pipeline.techniques.spectral.technique:Spectral"
