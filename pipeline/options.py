"""Bake options: one dataclass and its defaults, read by both the API and the CLI.

`BakeOptions` holds the general options, written out here, and every registered technique's
options (`registry.ENTRIES`, each its ``options_type``) flattened as ``<technique>_<field>``:
those are the TOML keys and, with dashes, the ``bake`` flags. A technique registered before this
module is first imported gets its fields, flags and checks without a change here.
"""

from __future__ import annotations

import json
import os
import sys
import threading
from dataclasses import Field, asdict, dataclass, field, fields, make_dataclass, replace

from sssbake.pipeline.core.profile_models import DEFAULT_PROFILE, PROFILE_MODELS
from sssbake.pipeline.core.ranges import SCALE_MM, Range, shown
from sssbake.pipeline.mesh.atlas_resolution import RESOLUTION
from sssbake.pipeline.techniques import registry

OPAQUE = "opaque"
#: Techniques `bake` can run.
TECHNIQUES = registry.NAMES
#: Per-asset limits (`asset_process`), sized for the 800k-vertex dragon (dragon_subdiv2.ply, skin2 at
#: 10 mm, default techniques: screen) on 2 shared cores: 430 s and 1.79 GiB peak resident memory of
#: the batch's process tree (the atlas 405 s of it). A prt bake of it (K = 200 took 64 s and 4.6 GB at
#: 200k vertices, docs/techniques/prt.md) scales to about 4x that memory, hence 16 GiB; an hour is 8x the measured bake.
ASSET_TIMEOUT_S = 3600.0
ASSET_MEMORY_GIB = 16.0
#: Fields that bound a bake's worker but do not shape its outputs: no part of `BakeOptions.to_json`,
#: so that a changed limit rebakes nothing.
SUPERVISION = ("asset_timeout_s", "asset_memory_gib")
#: ``--techniques auto`` ships a technique only when its object RMSE on the pilot's subsample is under
#: (1 - this) x best-fit Lambert's: the subsample's figures err (benchmarks/README.md#pilot-subsample),
#: and a technique that barely beats Lambert there buys nothing for its bytes and frame time.
LAMBERT_MARGIN = 0.1

# The ranges of the numeric options (`Range`; a technique's own are its ``option(range=...)``):
# `check_options` refuses a value outside with the range, the ``bake`` flags' help gives it, and
# docs/ranges.md lists them all with the materials'. Each end keeps clear of where the bake's
# arithmetic stops being finite (or a wait or a count stops being possible); tests/test_ranges.py
# bakes at both ends.
#: Seconds: Python's waits refuse a timeout past `threading.TIMEOUT_MAX` (~292 years on Linux).
TIMEOUT_S = Range(0.0, float(threading.TIMEOUT_MAX), "Python's waits take no longer timeout", "s",
                  says=f"a finite number >= 0 and at most {threading.TIMEOUT_MAX:.4g} s (0: no limit)")
#: GiB: a 64-bit address space holds 2^34 GiB; the limit in bytes stays an exact float64.
MEMORY_GIB = Range(0.0, 2.0**34, "a 64-bit address space holds 2^34 GiB", "GiB",
                   says="a finite number >= 0 and at most 2^34 GiB (0: no limit)")
#: Bytes per vertex: any positive finite number (the planner doubles and halves it, `plan.planned_candidate`).
BYTES_PER_VERTEX = Range(0.0, sys.float_info.max, "finite", "bytes", low_open=True, says="a positive finite number")


def _ranged(default, allowed: Range):
    return field(default=default, metadata={"range": allowed})


# The general fields come in two groups, before and after the techniques', in the order
# `to_json` has always written them.
@dataclass(frozen=True)
class _General:
    material: str | dict = "marble"
    scale_mm: float | None = _ranged(None, SCALE_MM)
    materials: tuple[tuple[str, str | dict], ...] = ()
    atlas_resolution: int = _ranged(RESOLUTION, Range(16, 8192, "the atlas sizes the bake supports", "texels"))
    atlas_padding: int = 4
    thickness_rays: int = _ranged(1, Range(1, 64, "rays per sample", "rays"))
    validate: bool = True
    techniques: tuple[str, ...] = ("auto",)
    profile: str = DEFAULT_PROFILE
    khr_materials_volume_scatter: bool = False


@dataclass(frozen=True)
class _Limits:
    max_bytes_per_vertex: float | None = _ranged(None, BYTES_PER_VERTEX)
    budget_rmse: float | None = _ranged(None, Range(0.0, 1.0, "an image RMSE", low_open=True, high_open=True,
                                                    says="an image RMSE in (0, 1)"))
    lambert_margin: float = _ranged(LAMBERT_MARGIN, Range(-sys.float_info.max, 1.0, "(1 - margin) x Lambert's RMSE "
                                                          "must be positive and finite", high_open=True,
                                                          says="a finite number below 1"))
    allow_roots: tuple[str, ...] = ()
    asset_timeout_s: float = _ranged(ASSET_TIMEOUT_S, TIMEOUT_S)
    asset_memory_gib: float = _ranged(ASSET_MEMORY_GIB, MEMORY_GIB)


class _BakeOptions:
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
    profile : str
        The diffusion profile every material is evaluated with (`materials.PROFILE_MODELS`):
        ``"montecarlo"`` (the default) matches a Monte Carlo random walk; ``"dipole"`` is the
        classical dipole of Jensen et al. 2001, to reproduce the papers.
    khr_materials_volume_scatter : bool
        Also write Khronos's draft ``KHR_materials_volume_scatter`` on each translucent material of
        the .glb, with the ``KHR_materials_volume`` attenuation it redefines as the extinction σ'_t
        instead of the fallback's σ_tr (`gltf.glb_pieces`). Off by default: the extension is a
        draft, and viewers without it read the σ'_t attenuation as plain absorption.
    <technique>_<field>
        Each registered technique's options (``techniques/<technique>/options.py``), e.g.
        ``prt_directions``; `technique_options` gives them as the technique's dataclass.
    max_bytes_per_vertex : float or None
        ``--techniques auto``: the most bytes per vertex the planner may spend (a prt it chooses
        gets it as its ``prt_byte_budget``).
    budget_rmse : float or None
        The image RMSE (`verify.verify_file`'s ``rmse_image``) each baked technique should stay
        under: the bake checks it on the full asset (`plan_check`), and with ``--techniques auto``
        a pilot chooses the parameters (`plan_pilot`) and the check moves them when it fails.
    lambert_margin : float
        ``--techniques auto`` ships a planned technique only when the pilot measures its object RMSE
        under (1 - this) x best-fit Lambert's on the subsample (`LAMBERT_MARGIN`); below 1, negative
        to tolerate a technique that much worse than Lambert.
    allow_roots : tuple of str
        Folders besides each asset's own that the files it references (glTF buffers and images,
        USD layers and textures, OBJ material libraries) may lie in (`confine.Confinement`).
    asset_timeout_s : float
        Seconds the asset's worker process may run before it is killed and the asset fails; 0: no
        limit.
    asset_memory_gib : float
        GiB of resident memory the asset's worker and its children may hold together before they
        are killed and the asset fails; 0: no limit.
    """

    def technique_options(self, name: str):
        """The options of the technique called `name`, as its ``options_type`` dataclass."""
        options_type = registry.entry(name).options_type
        return options_type(**{f.name: getattr(self, f"{name}_{f.name}") for f in fields(options_type)})

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
        if isinstance(overrides.get("materials"), dict):  # a TOML table
            overrides = {**overrides, "materials": tuple(overrides["materials"].items())}
        return replace(self, **overrides)


def _copied(f: Field, name: str, **metadata) -> tuple[str, str, Field]:
    """`f` as a `make_dataclass` field called `name`, its metadata extended by `metadata`."""
    return name, f.type, field(default=f.default, metadata={**f.metadata, **metadata})


BakeOptions = make_dataclass(
    "BakeOptions",
    [*(_copied(f, f.name) for f in fields(_General)),
     *(_copied(f, f"{t.name}_{f.name}", technique=t.name, option=f.name)
       for t in registry.ENTRIES for f in fields(t.options_type)),
     *(_copied(f, f.name) for f in fields(_Limits))],
    bases=(_BakeOptions,), frozen=True,
    # pickled into batch workers: found by module and name
    namespace={"__module__": __name__, "__doc__": _BakeOptions.__doc__},
)
BAKE_DEFAULTS = BakeOptions()
_FIELDS = {f.name: f for f in fields(BakeOptions)}


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


def check_value(name: str, value) -> None:
    """Raise ValueError naming option `name` when `value` is not of its declared kind or outside its
    range (its field's ``range``), whatever the other options hold.

    TOML and JSON carry ``true`` and ``512.5`` where a number or a whole number is meant; Python
    takes a bool for an int, so without this ``scale_mm = true`` would bake at 1 mm per unit.
    """
    f = _FIELDS.get(name)
    if f is None:
        raise ValueError(f"unknown option {shown(name)}; known: {sorted(_FIELDS)}")
    kind = f.type.removesuffix(" | None")
    if value is None and f.type.endswith(" | None"):
        return
    if kind == "int" and (isinstance(value, bool) or not isinstance(value, int)):
        raise ValueError(f"{name} must be a whole number, got {shown(value)}")
    if kind == "float" and (isinstance(value, bool) or not isinstance(value, (int, float))):
        raise ValueError(f"{name} must be a number, got {shown(value)}")
    if kind in ("bool", "str") and not isinstance(value, {"bool": bool, "str": str}[kind]):
        raise ValueError(f"{name} must be {'true or false' if kind == 'bool' else 'a string'}, got {shown(value)}")
    if name == "material" and not isinstance(value, (str, dict)):
        raise ValueError(f"material must be a preset name, 'opaque' or a table, got {shown(value)}")
    if name == "techniques" and not (isinstance(value, tuple) and all(isinstance(t, str) for t in value)):
        raise ValueError(f"techniques must be a list of technique names, got {shown(value)}")
    if name == "materials" and not (isinstance(value, tuple) and all(
            isinstance(m, tuple) and len(m) == 2 and isinstance(m[0], str) and isinstance(m[1], (str, dict))
            for m in value)):
        raise ValueError(f"materials must be a table of name pattern = material, got {shown(value)}")
    if name == "allow_roots" and not (isinstance(value, tuple) and all(isinstance(r, str) and r for r in value)):
        raise ValueError(f"allow_roots must be a list of folder paths, got {shown(value)}")
    if "range" in f.metadata:
        f.metadata["range"].check(name, value)


def check_options(o: BakeOptions) -> None:
    """Raise ValueError with a one-line reason for an impossible setting."""
    for f in _FIELDS.values():
        check_value(f.name, getattr(o, f.name))
    if not (0 <= o.atlas_padding <= o.atlas_resolution // 8):
        raise ValueError(f"atlas_padding must be in [0, resolution/8], got {o.atlas_padding}")
    if o.profile not in PROFILE_MODELS:
        raise ValueError(f"profile must be one of {', '.join(PROFILE_MODELS)}, got {shown(o.profile)}")
    unknown = sorted(set(o.techniques) - set(TECHNIQUES) - {"auto"})
    if unknown:
        raise ValueError(f"unknown technique(s) {shown(unknown)}; available: {list(TECHNIQUES)}, auto or none")
    if "auto" in o.techniques and len(o.techniques) > 1:
        raise ValueError("techniques: auto plans every technique itself; give it alone")
    for t in registry.ENTRIES:
        o.technique_options(t.name).check()
    missing = [r for r in o.allow_roots if not os.path.isdir(r)]
    if missing:
        raise ValueError(f"allow_roots: {shown(missing[0])} is not a folder")
    for name in ("spectral_variant", "spectral_basis"):
        if getattr(o, name) and "spectral" not in o.techniques:
            raise ValueError(f"{name} needs the spectral technique (--techniques spectral)")
    check_material(o.material, "material", o.profile)
    for pattern, spec in o.materials:
        check_material(spec, pattern, o.profile)


#: `check_material`'s verdicts: a config's rules and a batch's assets name the same few materials,
#: and an albedo spec costs a root search per channel.
_MATERIAL_PROBLEMS: dict[tuple, str | None] = {}


def check_material(spec, name: str, profile: str) -> None:
    """Raise ValueError (`material_from_spec`'s one line) when the material `spec` called `name`
    is impossible under the profile model `profile`; ``"opaque"`` is a material."""
    # numpy's: imported by a check, not with this module, which the CLI's help reads
    from sssbake.pipeline.core.materials import MaterialError, material_from_spec

    if isinstance(spec, str) and spec.lower() == OPAQUE:
        return
    try:
        key = (json.dumps(spec, sort_keys=True), name, profile)
    except (TypeError, ValueError):  # not JSON (an API caller's value): checked every time
        key = None
    if key is not None and key in _MATERIAL_PROBLEMS:
        problem = _MATERIAL_PROBLEMS[key]
    else:
        try:
            material_from_spec(spec, name, profile)
            problem = None
        except MaterialError as e:
            problem = str(e)
        if key is not None:
            _MATERIAL_PROBLEMS[key] = problem
    if problem is not None:
        raise ValueError(problem)
