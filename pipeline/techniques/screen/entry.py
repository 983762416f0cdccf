"""screen: what `registry` lists before importing the technique (`entry.TechniqueEntry`): its name,
options and ``sssbake tradeoff`` flags, with the sweeps' defaults."""

from __future__ import annotations

import argparse

from sssbake.pipeline.techniques.entry import TechniqueEntry, add_sweep_argument
from sssbake.pipeline.techniques.screen.options import ScreenOptions

SAMPLES = (8, 16, 32, 64, 128)
UNIFORM = (0, 4, 8, 16, 32)


class ScreenEntry(TechniqueEntry):
    name = "screen"
    options_type = ScreenOptions
    implementation = "sssbake.pipeline.techniques.screen.technique:Screen"

    def add_tradeoff_arguments(self, parser: argparse.ArgumentParser) -> None:
        add_sweep_argument(parser, "--samples", int, SAMPLES, "screen: importance samples N swept")
        add_sweep_argument(parser, "--uniform", int, UNIFORM, "screen: uniform samples U swept")
        parser.add_argument("--reference-subdivisions", type=int, default=0,
                            help="screen: midpoint subdivisions of the surface the per-vertex reference is computed "
                                 "on (the technique shades per pixel; default 0)")
