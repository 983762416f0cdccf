"""The kernels technique's registry object (`technique.Technique`), one mixin per concern
and its entry (``entry.py``: its name, options and tradeoff flags)."""

from __future__ import annotations

from sssbake.pipeline.techniques.kernels.entry import KernelsEntry
from sssbake.pipeline.techniques.kernels.stage import KernelsStage
from sssbake.pipeline.techniques.kernels.tradeoff import KernelsTradeoff
from sssbake.pipeline.techniques.kernels.verify import KernelsVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Kernels(KernelsStage, KernelsVerify, KernelsTradeoff, KernelsEntry, Technique):
    scope = MESH
    stage_version = 6
    needs_atlas = True
    draw_unit = "mesh"
    vertex_keys = ("sss:kernels:",)  # _SSS_KERNELS_VERTEX (layout.VERTEX_KEY)
