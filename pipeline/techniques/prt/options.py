"""prt: its bake options (`BakeOptions`' ``prt_*`` fields, TOML keys and ``--prt-*`` flags)."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.core.scatter_operator import SCATTER_DEFAULTS
from sssbake.pipeline.core.sh import MAX_ORDER
from sssbake.pipeline.techniques.option import option
from sssbake.pipeline.techniques.prt.compress import (
    MODES,
    PRT_COMPRESS_DEFAULTS,
    TABLES,
    WEIGHT_BITS,
    WEIGHTS,
    PrtCompressOptions,
)

_D = PRT_COMPRESS_DEFAULTS


@dataclass(frozen=True)
class PrtOptions:
    """Attributes
    ----------
    directions : int
        Light directions K.
    energy_dropped : float
        Fraction of R_d the gather radius may drop.
    mode, reference_fraction, sh_order, weights, tables, refine, weight_bits, byte_budget, reference_floor,
    detail_order
        The compression (`compress.PrtCompressOptions`).
    """

    directions: int = option(200, "prt: light directions K (default {default})")
    energy_dropped: float = option(SCATTER_DEFAULTS.energy_dropped,
                                   "prt: fraction of R_d the gather radius may drop (default {default})")
    mode: str = option(_D.mode, "prt compression (default {default})", choices=MODES)
    reference_fraction: float = option(_D.reference_fraction, "prt: reference points per vertex (default {default})")
    sh_order: int = option(_D.sh_order, "prt: SH order of Δq (default {default})")
    weights: str = option(_D.weights, "prt: reference weights (default {default})", choices=WEIGHTS)
    tables: str = option(_D.tables, "prt: reference tables, one per channel (rgb), one shared by the channels, "
                                    "or auto: shared unless the channels' directional shapes differ more than "
                                    "one shape can follow (default {default})", choices=TABLES)
    refine: float = option(_D.refine, "prt: share of the reference points placed where the fit is worst "
                                      "(default {default})")
    weight_bits: int = option(_D.weight_bits, "prt: bits per weight code; 8 packs them with the triangle in 4 bytes "
                                              "(default {default})", choices=WEIGHT_BITS)
    byte_budget: float | None = option(_D.byte_budget, "prt: bytes per vertex to spend; sets the reference count "
                                                       "(default: from the fraction)")
    reference_floor: int = option(_D.reference_floor, "prt: at least this many reference points (all vertices of "
                                                      "smaller meshes; default {default})")
    detail_order: int = option(_D.detail_order, "prt: SH order of each reference point's detail term with shared "
                                                "tables, 0 for none (default {default})")

    def compress(self) -> PrtCompressOptions:
        return PrtCompressOptions(self.mode, self.reference_fraction, self.sh_order, self.weights, tables=self.tables,
                                  refine=self.refine, weight_bits=self.weight_bits, byte_budget=self.byte_budget,
                                  reference_floor=self.reference_floor, detail_order=self.detail_order)

    def check(self) -> None:
        """Raise ValueError with a one-line reason (naming the ``prt_*`` option) for an impossible setting."""
        if not (4 <= self.directions <= 4096):
            raise ValueError(f"prt_directions must be in [4, 4096], got {self.directions}")
        if not (0.0 < self.energy_dropped < 0.5):
            raise ValueError(f"prt_energy_dropped must be in (0, 0.5), got {self.energy_dropped}")
        if self.mode not in MODES or self.weights not in WEIGHTS:
            raise ValueError(f"prt_mode must be one of {list(MODES)} and prt_weights one of {list(WEIGHTS)}, "
                             f"got {self.mode!r}, {self.weights!r}")
        if self.tables not in TABLES:
            raise ValueError(f"prt_tables must be one of {list(TABLES)}, got {self.tables!r}")
        if self.weight_bits not in WEIGHT_BITS:
            raise ValueError(f"prt_weight_bits must be one of {list(WEIGHT_BITS)}, got {self.weight_bits!r}")
        if self.byte_budget is not None and not self.byte_budget > 0:
            raise ValueError(f"prt_byte_budget must be a positive number of bytes per vertex, got {self.byte_budget!r}")
        if not self.reference_floor >= 0:
            raise ValueError(f"prt_reference_floor must be a whole number >= 0, got {self.reference_floor!r}")
        if not (0 <= self.detail_order <= MAX_ORDER):
            raise ValueError(f"prt_detail_order must be a whole number in [0, {MAX_ORDER}], got {self.detail_order!r}")
        if not (0.0 <= self.refine < 1.0):
            raise ValueError(f"prt_refine must be in [0, 1), got {self.refine}")
        if not (0.0 < self.reference_fraction <= 1.0):
            raise ValueError(f"prt_reference_fraction must be in (0, 1], got {self.reference_fraction}")
        if self.mode == "sh" and self.sh_order < 1:
            raise ValueError("prt_mode 'sh' needs prt_sh_order >= 1 (it has no reference points)")
        if not (0 <= self.sh_order <= MAX_ORDER) or self.directions < self.sh_order**2:
            raise ValueError(f"prt_sh_order must be in [0, {MAX_ORDER}] with prt_directions >= order², "
                             f"got {self.sh_order}")
