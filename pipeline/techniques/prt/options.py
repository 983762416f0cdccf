"""prt: its bake options (`BakeOptions`' ``prt_*`` fields, TOML keys and ``--prt-*`` flags) and the
compression's, with their choices: no numpy here, so that ``sssbake bake --help`` imports none."""

from __future__ import annotations

from dataclasses import dataclass

from sssbake.pipeline.core.scatter_options import SCATTER_DEFAULTS
from sssbake.pipeline.techniques.option import option

MODES = ("refs+sh", "sh", "lloyd")
WEIGHTS = ("barycentric", "least_squares", "best_fit")
TABLES = ("auto", "shared", "rgb")
WEIGHT_BITS = (8, 16)


@dataclass(frozen=True)
class PrtCompressOptions:
    """Attributes
    ----------
    mode : str
        ``"refs+sh"`` (the paper's scheme), ``"sh"`` (SH of q alone, no reference points) or
        ``"lloyd"`` (every vertex its own reference point: the uncompressed 8-bit baseline).
    reference_fraction : float
        Reference points as a fraction of the vertices (``refs+sh``), in (0, 1]. The default keeps
        the marble bunny (35k vertices) and dragon (50k) within 20 B/vertex (`compress.bytes_per_vertex`);
        smaller meshes pay more per vertex for the fixed direction tables (~1.3 B at 35k).
    sh_order : int
        SH order n of Δq (n² coefficients per channel, 0 for none; ``sh`` needs at least 1).
    weights : str
        ``"barycentric"`` (the paper), ``"least_squares"`` (fitted to q on the vertex's geometric
        triangle, channels sharing them) or ``"best_fit"`` (least squares on whichever triangle
        sharing a corner with the geometric one fits best; see `compress.best_fit_triangles`).
    dq_percentile : float or None
        Int8 range of each Δq coefficient: this percentile of its |values| (100: the largest,
        nothing clips), or None for the range with the least squared coding error per channel
        and coefficient (`compress.int8_scales`).
    reference_count : int or None
        Reference points wanted; overrides `reference_fraction` when given.
    reference_floor : int
        At least this many reference points from `reference_fraction` (every vertex on meshes
        that have fewer): a small mesh pays ~10 KB of direction tables anyway, and at 6.5 % its
        few points lose to plain Lambert (benchmarks/README.md#prt-compression).
    byte_budget : float or None
        Bytes per vertex to spend (``refs+sh``; `compress.bytes_per_vertex` total): the reference count
        becomes the most that fits (`compress.budget_reference_count`), overriding `reference_fraction`
        and `reference_count`. For small meshes, whose fixed tables cost more per vertex.
    sh_method : str
        ``"lsq"`` or ``"quadrature"`` projection of Δq (see `sh.sh_fit_matrix`).
    tables : str
        Reference tables (``refs+sh``): ``"rgb"`` (the paper: K codes per channel), ``"shared"``
        (K codes per reference point for all channels, a level per channel for each code, times
        the point's RGB colour; see `compress.shared_tables`) or ``"auto"``: shared unless the channels'
        directional shapes differ more than one shape can follow (`compress.resolve_tables`) and RGB tables
        fit `byte_budget`. ``lloyd`` always stores RGB.
    detail_order : int
        With shared tables, SH order of each reference point's detail term (`compress.detail_tables`;
        order² int8 coefficients and an int8 RGB colour per point, 0 for none). One shape per
        point cannot follow the channels' different shadow edges (red diffuses farther), which on
        dense smooth meshes is most of the error: there order 4 lowers it at the same bytes. On
        meshes whose error is the interpolation between points it gains nothing and doubles the
        vertex shader's time, hence off by default: turn it on for dense meshes
        (benchmarks/README.md#prt-compression).
    refine : float
        Share of the reference points (``refs+sh``) added where the fit is worst
        (`compress.refine_reference_points`) after simplification placed the rest, in [0, 1).
    weight_bits : int
        8 or 16 bits per weight code; 16 is used above 65536 reference triangles. The choice
        was made when 8-bit weights shared a 4-byte attribute with the triangle; the file now
        stores both as float32 at the same bytes (`prt_layout`), so 8 only rounds coarser
        (benchmarks/README.md#prt-compression, #vertex-attribute-encodings).
    """

    mode: str = "refs+sh"
    reference_fraction: float = 0.065
    sh_order: int = 0
    weights: str = "best_fit"
    dq_percentile: float | None = None
    reference_count: int | None = None
    byte_budget: float | None = None
    sh_method: str = "lsq"
    tables: str = "auto"
    refine: float = 0.6
    weight_bits: int = 8
    reference_floor: int = 256
    detail_order: int = 0


PRT_COMPRESS_DEFAULTS = PrtCompressOptions()
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
        The compression (`PrtCompressOptions`).
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
        from sssbake.pipeline.core.sh import MAX_ORDER  # numpy's: imported by a check, not by the CLI's help

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
