"""Bake options: one dataclass and its defaults, read by both the API and the CLI."""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, fields, replace

from .kernels_layout import KERNEL_BITS
from .kernels_precompute import KERNELS_DEFAULTS, KernelsOptions
from .lpv_grid import LPV_GRID_DEFAULTS, LpvGridOptions
from .lpv_propagate import MAX_STEPS
from .lpv_stage import FIELDS as LPV_FIELDS
from .marble_field import MARBLE_DEFAULTS, MarbleOptions
from .prt_compress import MODES, PRT_COMPRESS_DEFAULTS, TABLES, WEIGHT_BITS, WEIGHTS, PrtCompressOptions
from .scatter_operator import SCATTER_DEFAULTS
from .screen_samples import SCREEN_DEFAULTS, ScreenOptions
from .sh import MAX_ORDER
from .spectral_precompute import SPECTRAL_DEFAULTS, SpectralOptions

OPAQUE = "opaque"
#: Techniques `bake` can run.
TECHNIQUES = ("prt", "kernels", "spectral", "screen", "lpv")
#: Step counts the lpv rendering's scale is tabulated for by default (the runtime may use 1..this).
LPV_MAX_STEPS = 64
#: Per-asset limits (`asset_process`), sized for the 800k-vertex dragon (dragon_subdiv2.ply, skin2 at
#: 10 mm, default techniques: screen) on 2 shared cores: 430 s and 1.79 GiB peak resident memory of
#: the batch's process tree (the atlas 405 s of it). A prt bake of it (K = 200 took 64 s and 4.6 GB at
#: 200k vertices, README) scales to about 4x that memory, hence 16 GiB; an hour is 8x the measured bake.
ASSET_TIMEOUT_S = 3600.0
ASSET_MEMORY_GIB = 16.0
#: Fields that bound a bake's worker but do not shape its outputs: no part of `BakeOptions.to_json`,
#: so that a changed limit rebakes nothing.
SUPERVISION = ("asset_timeout_s", "asset_memory_gib")


@dataclass(frozen=True)
class BakeOptions:
    """Per-asset settings.

    Attributes
    ----------
    material : str or dict
        Scattering material for surfaces no material rule matches: a preset name, ``"opaque"``, or a
        table (see `materials.material_from_spec`).
    scale_mm : float or None
        Millimetres per file unit. None: use the unit the file format declares (glTF: metres;
        USD: metersPerUnit when authored); formats without units (OBJ, PLY, STL) then fail with a
        clear error rather than a guess.
    materials : tuple of (glob, spec)
        Source material name patterns (case-insensitive) mapped to material specs.
    atlas_resolution : int
        Atlas and thickness texture size in texels (square).
    atlas_padding : int
        Gutter between charts in texels (>= 4 so 7×7 kernels stay inside a chart).
    thickness_rays : int
        Rays per sample for the thickness bake (1: straight along -n).
    validate : bool
        Run the Khronos glTF validator and UsdValidation on every export.
    techniques : tuple of str
        Subsurface techniques to bake besides the standard fallback (see `TECHNIQUES`);
        ``("auto",)`` (the default): the planner (`plan.decide`) chooses per mesh and material;
        ``()`` (``"none"`` in a flag or config): the fallback only.
    prt_directions : int
        prt: light directions K.
    prt_energy_dropped : float
        prt: fraction of R_d the gather radius may drop.
    prt_mode, prt_reference_fraction, prt_sh_order, prt_weights, prt_tables, prt_refine, prt_weight_bits,
    prt_byte_budget, prt_reference_floor, prt_detail_order
        prt compression (see `prt_compress.PrtCompressOptions`).
    kernels_size, kernels_threshold, kernels_blend, kernels_seams, kernels_global_vertices
        kernels precompute (see `kernels_precompute.KernelsOptions`).
    kernels_bits : int
        kernels: bits per stored kernel weight (8 or 16).
    spectral_eigenpairs, spectral_width_mm, spectral_alpha, spectral_radius_mm
        spectral precompute (see `spectral_precompute.SpectralOptions`).
    spectral_variant : bool
        spectral: also write ``<stem>.sss_normals.glb``, whose standard NORMAL is the spectral
        subsurface normal (a stock viewer shows the effect).
    spectral_basis : bool
        spectral: also export the spectrum (coefficients, eigenvalues, residual, basis) so that a
        runtime can filter again.
    screen_samples, screen_uniform, screen_table_error
        screen precompute (see `screen_samples.ScreenOptions`): importance-sampled and uniform
        offsets, bound on the Rd table's relative interpolation error.
    lpv_resolution, lpv_padding, lpv_supersample
        lpv grid (see `lpv_grid.LpvGridOptions`): cells along the longest side, empty cells
        around, occupancy samples per cell side.
    lpv_field : str
        lpv medium: ``"homogeneous"`` (the material everywhere) or ``"marble"`` (veins through it,
        `marble_field`).
    lpv_vein_mm : float
        lpv marble: spacing of the veins, mm.
    lpv_max_steps : int
        lpv: the rendering's scale is tabulated for 1 .. this many propagation steps.
    max_bytes_per_vertex : float or None
        ``--techniques auto``: the most bytes per vertex the planner may spend (a prt it chooses
        gets it as its ``prt_byte_budget``).
    allow_roots : tuple of str
        Folders besides each asset's own that the files it references (glTF buffers and images,
        USD layers and textures, OBJ material libraries) may lie in (`confine.Confinement`).
    asset_timeout_s : float
        Seconds the asset's worker process may run before it is killed and the asset fails; 0: no
        limit.
    asset_memory_gib : float
        GiB of resident memory the asset's worker and its children may hold together before they
        are killed and the asset fails; 0: no limit.
    budget_rmse : float or None
        The image RMSE (`verify.verify_file`'s ``rmse_image``) each baked technique should stay
        under: the bake checks it on the full asset (`plan_check`), and with ``--techniques auto``
        a pilot chooses the parameters (`plan_pilot`) and the check moves them when it fails.
    """

    material: str | dict = "marble"
    scale_mm: float | None = None
    materials: tuple[tuple[str, str | dict], ...] = ()
    atlas_resolution: int = 512
    atlas_padding: int = 4
    thickness_rays: int = 1
    validate: bool = True
    techniques: tuple[str, ...] = ("auto",)
    prt_directions: int = 200
    prt_energy_dropped: float = SCATTER_DEFAULTS.energy_dropped
    prt_mode: str = PRT_COMPRESS_DEFAULTS.mode
    prt_reference_fraction: float = PRT_COMPRESS_DEFAULTS.reference_fraction
    prt_sh_order: int = PRT_COMPRESS_DEFAULTS.sh_order
    prt_weights: str = PRT_COMPRESS_DEFAULTS.weights
    prt_tables: str = PRT_COMPRESS_DEFAULTS.tables
    prt_refine: float = PRT_COMPRESS_DEFAULTS.refine
    prt_weight_bits: int = PRT_COMPRESS_DEFAULTS.weight_bits
    prt_byte_budget: float | None = PRT_COMPRESS_DEFAULTS.byte_budget
    prt_reference_floor: int = PRT_COMPRESS_DEFAULTS.reference_floor
    prt_detail_order: int = PRT_COMPRESS_DEFAULTS.detail_order
    kernels_size: int = KERNELS_DEFAULTS.kernel_size
    kernels_threshold: float = KERNELS_DEFAULTS.threshold
    kernels_blend: str = KERNELS_DEFAULTS.blend
    kernels_seams: str = KERNELS_DEFAULTS.seams
    kernels_global_vertices: int = KERNELS_DEFAULTS.global_vertices
    # 8-bit codes: the hand's image RMSE is 0.0074747 against 0.0074749 with 16, in 27 % less file
    kernels_bits: int = 8
    spectral_eigenpairs: int = SPECTRAL_DEFAULTS.eigenpairs
    spectral_width_mm: float | None = SPECTRAL_DEFAULTS.width_mm
    spectral_alpha: float = SPECTRAL_DEFAULTS.alpha
    spectral_radius_mm: float | None = SPECTRAL_DEFAULTS.radius_mm
    spectral_variant: bool = False
    spectral_basis: bool = False
    screen_samples: int = SCREEN_DEFAULTS.samples
    screen_uniform: int = SCREEN_DEFAULTS.uniform
    screen_table_error: float = SCREEN_DEFAULTS.table_error
    lpv_resolution: int = LPV_GRID_DEFAULTS.resolution
    lpv_padding: int = LPV_GRID_DEFAULTS.padding
    lpv_supersample: int = LPV_GRID_DEFAULTS.supersample
    lpv_field: str = "homogeneous"
    lpv_vein_mm: float = MARBLE_DEFAULTS.vein_mm
    lpv_max_steps: int = LPV_MAX_STEPS
    max_bytes_per_vertex: float | None = None
    budget_rmse: float | None = None
    allow_roots: tuple[str, ...] = ()
    asset_timeout_s: float = ASSET_TIMEOUT_S
    asset_memory_gib: float = ASSET_MEMORY_GIB

    def prt_compress(self) -> PrtCompressOptions:
        return PrtCompressOptions(self.prt_mode, self.prt_reference_fraction, self.prt_sh_order, self.prt_weights,
                                  tables=self.prt_tables, refine=self.prt_refine, weight_bits=self.prt_weight_bits,
                                  byte_budget=self.prt_byte_budget, reference_floor=self.prt_reference_floor,
                                  detail_order=self.prt_detail_order)

    def kernels(self) -> KernelsOptions:
        return KernelsOptions(self.kernels_size, self.kernels_threshold, self.kernels_blend, self.kernels_seams,
                              global_vertices=self.kernels_global_vertices)

    def spectral(self) -> SpectralOptions:
        return SpectralOptions(self.spectral_eigenpairs, self.spectral_width_mm, self.spectral_alpha,
                               self.spectral_radius_mm)

    def screen(self) -> ScreenOptions:
        return ScreenOptions(self.screen_samples, self.screen_uniform, self.screen_table_error)

    def lpv_grid(self) -> LpvGridOptions:
        return LpvGridOptions(self.lpv_resolution, self.lpv_padding, self.lpv_supersample)

    def lpv_marble(self) -> MarbleOptions:
        return MarbleOptions(vein_mm=self.lpv_vein_mm)

    def to_json(self) -> dict:
        """The options that shape the outputs (all but `SUPERVISION`), as JSON values."""
        return {k: v for k, v in asdict(self).items() if k not in SUPERVISION}

    def merged(self, overrides: dict) -> "BakeOptions":
        """A copy with `overrides` applied; unknown keys raise ValueError naming them."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown option(s) {unknown}; known: {sorted(known)}")
        if isinstance(overrides.get("techniques"), (list, tuple, str)):
            overrides = {**overrides, "techniques": parse_techniques(overrides["techniques"])}
        if isinstance(overrides.get("allow_roots"), list):  # TOML arrays
            overrides = {**overrides, "allow_roots": tuple(overrides["allow_roots"])}
        return replace(self, **overrides)


BAKE_DEFAULTS = BakeOptions()


def parse_techniques(value: str | list | tuple) -> tuple[str, ...]:
    """Technique names from a flag (``"prt,screen"``) or a config list; ``"none"`` alone means none."""
    names = value.split(",") if isinstance(value, str) else value
    if not all(isinstance(t, str) for t in names):
        raise ValueError(f"techniques must be names, got {value!r}")
    names = tuple(t.strip() for t in names if t.strip())
    if "none" in names:
        if len(names) > 1:
            raise ValueError("techniques: none bakes only the fallback; give it alone")
        return ()
    return names


def check_types(o: BakeOptions) -> None:
    """Raise ValueError naming the first option whose value is not of its declared kind.

    TOML and JSON carry ``true`` and ``512.5`` where a number or a whole number is meant; Python
    takes a bool for an int, so without this ``scale_mm = true`` would bake at 1 mm per unit.
    """
    for f in fields(o):
        value, kind = getattr(o, f.name), f.type.removesuffix(" | None")
        if value is None and f.type.endswith(" | None"):
            continue
        if kind == "int" and (isinstance(value, bool) or not isinstance(value, int)):
            raise ValueError(f"{f.name} must be a whole number, got {value!r}")
        if kind == "float" and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise ValueError(f"{f.name} must be a number, got {value!r}")
        if kind in ("bool", "str") and not isinstance(value, {"bool": bool, "str": str}[kind]):
            raise ValueError(f"{f.name} must be {'true or false' if kind == 'bool' else 'a string'}, got {value!r}")


def check_options(o: BakeOptions) -> None:
    """Raise ValueError with a one-line reason for an impossible setting."""
    check_types(o)
    if o.scale_mm is not None and not (0 < o.scale_mm < float("inf")):
        raise ValueError(f"scale_mm must be a finite number > 0, got {o.scale_mm!r}")
    if not (16 <= o.atlas_resolution <= 8192):
        raise ValueError(f"atlas_resolution must be in [16, 8192], got {o.atlas_resolution}")
    if not (0 <= o.atlas_padding <= o.atlas_resolution // 8):
        raise ValueError(f"atlas_padding must be in [0, resolution/8], got {o.atlas_padding}")
    if not (1 <= o.thickness_rays <= 64):
        raise ValueError(f"thickness_rays must be in [1, 64], got {o.thickness_rays}")
    unknown = sorted(set(o.techniques) - set(TECHNIQUES) - {"auto"})
    if unknown:
        raise ValueError(f"unknown technique(s) {unknown}; available: {list(TECHNIQUES)}, auto or none")
    if "auto" in o.techniques and len(o.techniques) > 1:
        raise ValueError("techniques: auto plans every technique itself; give it alone")
    if not (4 <= o.prt_directions <= 4096):
        raise ValueError(f"prt_directions must be in [4, 4096], got {o.prt_directions}")
    if not (0.0 < o.prt_energy_dropped < 0.5):
        raise ValueError(f"prt_energy_dropped must be in (0, 0.5), got {o.prt_energy_dropped}")
    if o.prt_mode not in MODES or o.prt_weights not in WEIGHTS:
        raise ValueError(f"prt_mode must be one of {list(MODES)} and prt_weights one of {list(WEIGHTS)}, "
                         f"got {o.prt_mode!r}, {o.prt_weights!r}")
    if o.prt_tables not in TABLES:
        raise ValueError(f"prt_tables must be one of {list(TABLES)}, got {o.prt_tables!r}")
    if o.prt_weight_bits not in WEIGHT_BITS:
        raise ValueError(f"prt_weight_bits must be one of {list(WEIGHT_BITS)}, got {o.prt_weight_bits!r}")
    if o.prt_byte_budget is not None and not o.prt_byte_budget > 0:
        raise ValueError(f"prt_byte_budget must be a positive number of bytes per vertex, got {o.prt_byte_budget!r}")
    if not o.prt_reference_floor >= 0:
        raise ValueError(f"prt_reference_floor must be a whole number >= 0, got {o.prt_reference_floor!r}")
    if not (0 <= o.prt_detail_order <= MAX_ORDER):
        raise ValueError(f"prt_detail_order must be a whole number in [0, {MAX_ORDER}], got {o.prt_detail_order!r}")
    if not (0.0 <= o.prt_refine < 1.0):
        raise ValueError(f"prt_refine must be in [0, 1), got {o.prt_refine}")
    if not (0.0 < o.prt_reference_fraction <= 1.0):
        raise ValueError(f"prt_reference_fraction must be in (0, 1], got {o.prt_reference_fraction}")
    o.kernels().check()
    if o.kernels_bits not in KERNEL_BITS:
        raise ValueError(f"kernels_bits must be one of {list(KERNEL_BITS)}, got {o.kernels_bits!r}")
    o.spectral().check()
    o.screen().check()
    o.lpv_grid().check()
    o.lpv_marble().check()
    if o.lpv_field not in LPV_FIELDS:
        raise ValueError(f"lpv_field must be one of {list(LPV_FIELDS)}, got {o.lpv_field!r}")
    if o.max_bytes_per_vertex is not None and not o.max_bytes_per_vertex > 0:
        raise ValueError(f"max_bytes_per_vertex must be a positive number, got {o.max_bytes_per_vertex!r}")
    if o.budget_rmse is not None and not (0 < o.budget_rmse < 1):
        raise ValueError(f"budget_rmse must be an image RMSE in (0, 1), got {o.budget_rmse!r}")
    if not (1 <= o.lpv_max_steps <= MAX_STEPS):
        raise ValueError(f"lpv_max_steps must be a whole number in [1, {MAX_STEPS}], got {o.lpv_max_steps!r}")
    for name in SUPERVISION:
        if not (0 <= getattr(o, name) < float("inf")):
            raise ValueError(f"{name} must be a finite number >= 0 (0: no limit), got {getattr(o, name)!r}")
    if not (isinstance(o.allow_roots, tuple) and all(isinstance(r, str) and r for r in o.allow_roots)):
        raise ValueError(f"allow_roots must be a list of folder paths, got {o.allow_roots!r}")
    missing = [r for r in o.allow_roots if not os.path.isdir(r)]
    if missing:
        raise ValueError(f"allow_roots: {missing[0]!r} is not a folder")
    for name in ("spectral_variant", "spectral_basis"):
        if getattr(o, name) and "spectral" not in o.techniques:
            raise ValueError(f"{name} needs the spectral technique (--techniques spectral)")
    if o.prt_mode == "sh" and o.prt_sh_order < 1:
        raise ValueError("prt_mode 'sh' needs prt_sh_order >= 1 (it has no reference points)")
    if not (0 <= o.prt_sh_order <= MAX_ORDER) or o.prt_directions < o.prt_sh_order**2:
        raise ValueError(f"prt_sh_order must be in [0, {MAX_ORDER}] with prt_directions >= order², "
                         f"got {o.prt_sh_order}")
