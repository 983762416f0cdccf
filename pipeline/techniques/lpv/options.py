"""lpv: its bake options (`BakeOptions`' ``lpv_*`` fields, TOML keys and ``--lpv-*`` flags) and those of
its grid and marble field, with their limits: no numpy here, so that ``sssbake bake --help`` imports none."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from sssbake.pipeline.core.errors import SssbakeError
from sssbake.pipeline.core.ranges import LENGTH_MAX_MM, Range
from sssbake.pipeline.techniques.option import option

if TYPE_CHECKING:  # core.materials imports numpy; here it only names a field's type
    from sssbake.pipeline.core.materials import Material

#: Most propagation steps a frame may take (`propagate.LpvPropagateOptions`).
MAX_STEPS = 1024
#: Where a grid's coefficients can come from.
FIELDS = ("homogeneous", "marble")
#: The veins' spacing, mm: the noise indexes its lattice with int64 at point / vein_mm x 2^11 (the
#: 12th octave, `marble_field.fbm`), which holds 2^63 for points up to `LENGTH_MAX_MM` from the
#: origin down to 2.2e-4 mm (1e-300 overflowed the cast); above `LENGTH_MAX_MM` no object shows a vein.
VEIN_MM = Range(1e-3, LENGTH_MAX_MM, "the noise's int64 lattice index overflows below ~2e-4 mm", "mm")


class LpvGridError(SssbakeError, ValueError):
    """A surface, field or options the lpv voxelisation cannot work with."""


@dataclass(frozen=True)
class LpvGridOptions:
    """Attributes
    ----------
    resolution : int
        Cells along the longest side of the object's bounding box.
    padding : int
        Empty cells added around the object on every side, so light leaving it has a cell to go to.
    supersample : int
        Occupancy is the share of ``supersample³`` points per cell that are inside.
    """

    resolution: int = 32
    padding: int = 1
    supersample: int = 4

    def check(self) -> None:
        for name, lo, hi in (("resolution", 2, 512), ("padding", 0, 8), ("supersample", 1, 8)):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi):
                raise LpvGridError(f"lpv grid: {name} must be a whole number in [{lo}, {hi}], got {value!r}")


LPV_GRID_DEFAULTS = LpvGridOptions()


@dataclass(frozen=True)
class MarbleOptions:
    """Attributes
    ----------
    vein_mm : float
        Spacing of the veins along `axis`, mm.
    turbulence : float
        How far the noise bends the veins, in vein periods per unit of fBm (0: flat veins).
    octaves : int
        Octaves of the fBm.
    sharpness : float
        Exponent of the vein profile (>= 1); larger: thinner veins.
    axis : (3,) float
        Direction across the veins (normalised on use), object space.
    seed : int
    base : str or Material
        The marble's body (a preset name or a Material).
    vein_material : str, Material or None
        The veins' material; None: the base with `marble_field.VEIN_ABSORPTION` × its absorption.
    """

    vein_mm: float = 20.0
    turbulence: float = 1.0
    octaves: int = 5
    sharpness: float = 8.0
    axis: tuple[float, float, float] = (1.0, 0.4, 0.2)
    seed: int = 0
    base: str | Material = "marble"
    vein_material: str | Material | None = None

    def check(self) -> None:
        if not (isinstance(self.vein_mm, (int, float)) and math.isfinite(self.vein_mm) and self.vein_mm > 0):
            raise ValueError(f"marble: vein_mm must be a positive number, got {self.vein_mm!r}")
        if not (isinstance(self.turbulence, (int, float)) and 0 <= self.turbulence <= 100):
            raise ValueError(f"marble: turbulence must be in [0, 100], got {self.turbulence!r}")
        if not (isinstance(self.octaves, int) and 1 <= self.octaves <= 12):
            raise ValueError(f"marble: octaves must be a whole number in [1, 12], got {self.octaves!r}")
        if not (isinstance(self.sharpness, (int, float)) and 1 <= self.sharpness <= 1000):
            raise ValueError(f"marble: sharpness must be in [1, 1000], got {self.sharpness!r}")
        import numpy as np  # for a check, not for the CLI's help, which reads these options

        axis = np.asarray(self.axis, dtype=np.float64)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
            raise ValueError(f"marble: axis must be three finite numbers, not all 0, got {self.axis!r}")


MARBLE_DEFAULTS = MarbleOptions()


@dataclass(frozen=True)
class LpvOptions:
    """Attributes
    ----------
    resolution, padding, supersample
        The grid (`LpvGridOptions`): cells along the longest side, empty cells around,
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
