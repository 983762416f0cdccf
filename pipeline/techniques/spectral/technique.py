"""The spectral technique's registry object (`technique.Technique`), one mixin per concern."""

from __future__ import annotations

from sssbake.pipeline.techniques.spectral.options import SpectralOptions
from sssbake.pipeline.techniques.spectral.stage import SpectralStage
from sssbake.pipeline.techniques.spectral.tradeoff import SpectralTradeoff
from sssbake.pipeline.techniques.spectral.verify import SpectralVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Spectral(SpectralStage, SpectralVerify, SpectralTradeoff, Technique):
    name = "spectral"
    scope = MESH
    stage_version = 2
    needs_atlas = False
    options_type = SpectralOptions
    draw_unit = "mesh"
