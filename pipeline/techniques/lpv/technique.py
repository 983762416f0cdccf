"""The lpv technique's registry object (`technique.Technique`), one mixin per concern
and its entry (``entry.py``: its name, options and tradeoff flags)."""

from __future__ import annotations

from sssbake.pipeline.techniques.lpv.entry import LpvEntry
from sssbake.pipeline.techniques.lpv.pilot import LpvPilot
from sssbake.pipeline.techniques.lpv.stage import LpvStage
from sssbake.pipeline.techniques.lpv.tradeoff import LpvTradeoff
from sssbake.pipeline.techniques.lpv.verify import LpvVerify
from sssbake.pipeline.techniques.technique import MESH, Technique


class Lpv(LpvStage, LpvVerify, LpvPilot, LpvTradeoff, LpvEntry, Technique):
    scope = MESH
    stage_version = 2
    needs_atlas = False
    draw_unit = "mesh"
