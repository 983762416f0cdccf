"""screen: the planner's pilot (`technique.Technique`'s pilot hooks).

Candidates: importance samples N (`SCREEN_SAMPLES`); nothing per vertex, N costs frame time. When
no N meets the budget (light crossing a thin part, which screen space misses), prt's candidates
follow, unless the mesh deforms.
"""

from __future__ import annotations

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.techniques.screen.samples import screen_samples
from sssbake.pipeline.techniques.technique import Candidate

SCREEN_SAMPLES = (8, 16, 32, 64)


class ScreenPilot:
    """Sample counts, then prt's candidates on a rigid mesh (module docstring); every candidate is
    measured (the budget check scales the pilot's figures)."""

    pilot_fallback = "prt"

    def pilot_candidates(self, params: dict, options, vertices: int, deforming: bool) -> list[Candidate]:
        return [Candidate("screen", {"screen_samples": n}, f"screen, N = {n}") for n in SCREEN_SAMPLES]

    def pilot_item(self, options, surface: Surface, mm_per_unit: float, material: Material, vertices: int,
                   memo: dict) -> tuple[dict, bool]:
        samples = screen_samples(material, options.technique_options("screen").samples_options())
        return {"screen": samples, "mm_per_unit": mm_per_unit}, True
