"""The spectral technique's registry object (`technique.Technique`), one mixin per concern
and its entry (``entry.py``: its name, options and tradeoff flags)."""

from __future__ import annotations

from sssbake.pipeline.techniques.spectral.entry import SpectralEntry
from sssbake.pipeline.techniques.spectral.stage import SpectralStage
from sssbake.pipeline.techniques.spectral.tradeoff import SpectralTradeoff
from sssbake.pipeline.techniques.spectral.verify import SpectralVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Spectral(SpectralStage, SpectralVerify, SpectralTradeoff, SpectralEntry, Technique):
    scope = MESH
    stage_version = 2
    needs_atlas = False
    draw_unit = "mesh"
    vertex_keys = ("sss:normal", "sss:spectral:")  # _SSS_NORMAL, _SSS_SPECTRAL_VERTEX (layout.NORMAL_KEY, VERTEX_KEY)
