"""The kernels technique's registry object (`technique.Technique`), one mixin per concern."""

from __future__ import annotations

from sssbake.pipeline.techniques.kernels.options import KernelsOptions
from sssbake.pipeline.techniques.kernels.stage import KernelsStage
from sssbake.pipeline.techniques.kernels.tradeoff import KernelsTradeoff
from sssbake.pipeline.techniques.kernels.verify import KernelsVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Kernels(KernelsStage, KernelsVerify, KernelsTradeoff, Technique):
    name = "kernels"
    scope = MESH
    stage_version = 4
    needs_atlas = True
    options_type = KernelsOptions
    draw_unit = "mesh"
