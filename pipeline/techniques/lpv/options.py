"""lpv: its bake options (`BakeOptions`' ``lpv_*`` fields, TOML keys and ``--lpv-*`` flags)."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.core.ranges import LENGTH_MAX_MM, Range
from sssbake.pipeline.techniques.lpv.grid import LPV_GRID_DEFAULTS, LpvGridOptions
from sssbake.pipeline.techniques.lpv.marble_field import MARBLE_DEFAULTS, MarbleOptions
from sssbake.pipeline.techniques.lpv.propagate import MAX_STEPS
from sssbake.pipeline.techniques.option import option

#: Where a grid's coefficients can come from.
FIELDS = ("homogeneous", "marble")
#: The veins' spacing, mm: the noise indexes its lattice with int64 at point / vein_mm x 2^11 (the
#: 12th octave, `marble_field.fbm`), which holds 2^63 for points up to `LENGTH_MAX_MM` from the
#: origin down to 2.2e-4 mm (1e-300 overflowed the cast); above `LENGTH_MAX_MM` no object shows a vein.
VEIN_MM = Range(1e-3, LENGTH_MAX_MM, "the noise's int64 lattice index overflows below ~2e-4 mm", "mm")


@dataclass(frozen=True)
class LpvOptions:
    """Attributes
    ----------
    resolution, padding, supersample
        The grid (`grid.LpvGridOptions`): cells along the longest side, empty cells around,
        occupancy samples per cell side.
    field : str
        The medium: ``"homogeneous"`` (the material everywhere) or ``"marble"`` (veins through it,
        `marble_field`).
    vein_mm : float
        Marble: spacing of the veins, mm.
    max_steps : int
        The rendering's scale is tabulated for 1 .. this many propagation steps (the runtime may
        use any of them).
    """

    resolution: int = option(LPV_GRID_DEFAULTS.resolution,
                             "lpv: grid cells along the object's longest side (default {default:g})")
    padding: int = option(LPV_GRID_DEFAULTS.padding, "lpv: empty cells around the object (default {default:g})")
    supersample: int = option(LPV_GRID_DEFAULTS.supersample,
                              "lpv: occupancy samples per cell side (default {default:g})")
    field: str = option("homogeneous", "lpv: the medium, the material everywhere or marble veins through it "
                                       "(default {default})", choices=FIELDS)
    vein_mm: float = option(MARBLE_DEFAULTS.vein_mm,
                            "lpv: marble field: spacing of the veins, mm (default {default:g})", range=VEIN_MM)
    max_steps: int = option(64, "lpv: propagation steps the rendering's scale is tabulated for (default {default:g})")

    def grid(self) -> LpvGridOptions:
        return LpvGridOptions(self.resolution, self.padding, self.supersample)

    def marble(self) -> MarbleOptions:
        return MarbleOptions(vein_mm=self.vein_mm)

    def check(self) -> None:
        """Raise ValueError with a one-line reason (naming the ``lpv_*`` option) for an impossible setting."""
        self.grid().check()
        self.marble().check()
        if self.field not in FIELDS:
            raise ValueError(f"lpv_field must be one of {list(FIELDS)}, got {self.field!r}")
        if not (1 <= self.max_steps <= MAX_STEPS):
            raise ValueError(f"lpv_max_steps must be a whole number in [1, {MAX_STEPS}], got {self.max_steps!r}")
