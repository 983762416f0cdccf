"""kernels: what `registry` lists before importing the technique (`entry.TechniqueEntry`): its name,
options and ``sssbake tradeoff`` flags, with the sweeps' defaults."""

from __future__ import annotations

import argparse

from sssbake.pipeline.mesh.atlas_resolution import RESOLUTION
from sssbake.pipeline.techniques.entry import TechniqueEntry, add_sweep_argument
from sssbake.pipeline.techniques.kernels.options import KernelsOptions

RESOLUTIONS = (256, 512, 1024)
SIZES = (5, 7, 9)
THRESHOLDS = (1e-4, 1e-5, 1e-6)
#: Atlas resolution of the default configuration: the bake's.
DEFAULT_RESOLUTION = RESOLUTION


class KernelsEntry(TechniqueEntry):
    name = "kernels"
    options_type = KernelsOptions
    implementation = "sssbake.pipeline.techniques.kernels.technique:Kernels"

    def add_tradeoff_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--atlas-resolution", type=int, default=DEFAULT_RESOLUTION,
                            help="kernels: atlas resolution of the default configuration "
                                 f"(default {DEFAULT_RESOLUTION})")
        add_sweep_argument(parser, "--resolutions", int, RESOLUTIONS, "kernels: atlas resolutions swept")
        add_sweep_argument(parser, "--sizes", int, SIZES, "kernels: kernel sizes swept")
        add_sweep_argument(parser, "--thresholds", float, THRESHOLDS, "kernels: F thresholds swept")
