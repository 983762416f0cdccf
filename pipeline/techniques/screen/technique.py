"""The screen technique's registry object (`technique.Technique`), one mixin per concern
and its entry (``entry.py``: its name, options and tradeoff flags)."""

from __future__ import annotations

from sssbake.pipeline.techniques.screen.entry import ScreenEntry
from sssbake.pipeline.techniques.screen.pilot import ScreenPilot
from sssbake.pipeline.techniques.screen.stage import ScreenStage
from sssbake.pipeline.techniques.screen.tradeoff import ScreenTradeoff
from sssbake.pipeline.techniques.screen.verify import ScreenVerify
from sssbake.pipeline.techniques.technique import MATERIAL, Technique


class Screen(ScreenStage, ScreenVerify, ScreenPilot, ScreenTradeoff, ScreenEntry, Technique):
    scope = MATERIAL
    stage_version = 1
    needs_atlas = False
    draw_unit = "primitive"
