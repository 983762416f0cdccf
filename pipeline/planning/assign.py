"""Material assignment: which scattering material (or none) each source material gets, and why."""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, replace

import numpy as np

from sssbake.pipeline.core.engine_materials import single_scatter_albedo
from sssbake.pipeline.core.profile import total_for_albedo
from sssbake.pipeline.core.materials import (
    COEFFICIENT,
    DEFAULT_PROFILE,
    EXTINCTION,
    Material,
    MaterialError,
    material_from_spec,
)
from sssbake.pipeline.mesh.scene import Scene, SourceMaterial
from sssbake.pipeline.options import OPAQUE, BakeOptions

DEFAULT_MATERIAL_NAME = "sssbake_default"


@dataclass(frozen=True)
class Assignment:
    """Scattering material per scene material index (None: opaque), with a one-line reason each.

    `scene` is the input scene, plus a material for primitives that had none.
    """

    scene: Scene
    materials: dict[int, Material | None]
    reasons: dict[int, str]


def _spec_material(spec, name: str, profile: str) -> Material | None:
    if isinstance(spec, str) and spec.lower() == OPAQUE:
        return None
    return material_from_spec(spec, name, profile)


def material_from_khr_volume(src: SourceMaterial, mm_per_unit: float, profile: str = DEFAULT_PROFILE) -> Material | None:
    """Scattering parameters from a glTF KHR_materials_volume attenuation and the base colour.

    Inverts sssbake's own fallback: the attenuation gives σ_tr = -ln(c)/d per channel, the base
    colour is taken as the total diffuse reflectance R_d, which fixes α', and then
    σ'_t = σ_tr / sqrt(3(1 - α')). Returns None when the volume has no finite attenuation.
    """
    vol = src.volume or {}
    dist = vol.get("attenuationDistance")
    if dist is None or not np.isfinite(dist) or dist <= 0:
        return None
    colour = np.clip(np.asarray(vol.get("attenuationColor", [1, 1, 1]), dtype=np.float64), 1e-6, 1.0)
    sigma_tr = -np.log(colour) / (dist * mm_per_unit)  # 1/mm
    if np.all(sigma_tr <= 0):
        return None
    eta = float(src.ior or 1.5)
    rd_max = float(total_for_albedo(1.0 - 1e-9, eta, profile)[0])
    target = np.clip(np.asarray(src.base_color_factor[:3], dtype=np.float64), 1e-4, rd_max * (1 - 1e-6))
    # R_d is monotone in α': invert by bisection per channel.
    lo, hi = np.zeros(3), np.ones(3)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = total_for_albedo(mid, eta, profile) < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    alpha = 0.5 * (lo + hi)
    # A channel with no attenuation would need infinite σ'_t; borrow the smallest positive σ_tr.
    sigma_tr = np.where(sigma_tr > 0, sigma_tr, sigma_tr[sigma_tr > 0].min())
    st = sigma_tr / np.sqrt(3.0 * (1.0 - alpha))
    return Material(f"{src.name} (KHR_materials_volume)", alpha * st, (1.0 - alpha) * st, eta, profile)


def _numbers(value, count: int, what: str, src: SourceMaterial) -> np.ndarray:
    """`value` as `count` finite float64 numbers; MaterialError naming `src` and `what` otherwise."""
    try:
        out = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        out = np.empty(0)
    if out.size != count or not np.all(np.isfinite(out)):
        raise MaterialError(f"material {src.name!r}: {what} must be {count} finite number(s), got {value!r}")
    return out


def material_from_khr_volume_scatter(src: SourceMaterial, mm_per_unit: float,
                                     profile: str = DEFAULT_PROFILE) -> Material | None:
    """Scattering parameters from the draft KHR_materials_volume_scatter and the volume attenuation.

    The draft reads KHR_materials_volume's attenuation as the extinction σ_t = −ln(c)/d per channel,
    ``multiscatterColorFactor`` (or ``multiscatterColor``) as the single-scatter albedo ρ_ss = σ_s/σ_t through its fit
    (`engine_materials.single_scatter_albedo`) and ``scatterAnisotropy`` as the Henyey-Greenstein g;
    sssbake's reduced coefficients follow by the similarity relation: σ_a = (1 − ρ_ss) σ_t,
    σ'_s = (1 − g) ρ_ss σ_t. This inverts what `engine_materials.khr_materials_volume_scatter`
    writes (g = 0, σ_t = σ'_t) exactly; η is KHR_materials_ior's (glTF's default 1.5).

    A channel the file gives no extinction (colour 1) or an infinite one (colour 0) is held at the
    least extinction (`materials.EXTINCTION`) or the largest coefficient (`materials.COEFFICIENT`)
    sssbake bakes. Returns None when the volume has no attenuation distance > 0 (the draft's medium
    then never interacts).

    Raises
    ------
    MaterialError
        A property that is not numbers of the draft's count, or coefficients no material may have.
    """
    vol = src.volume or {}
    scatter = src.volume_scatter or {}
    if vol.get("attenuationDistance") is None:
        return None
    dist = float(_numbers(vol["attenuationDistance"], 1, "KHR_materials_volume attenuationDistance", src)[0])
    if dist <= 0:
        return None
    colour = np.clip(_numbers(vol.get("attenuationColor", [1.0, 1.0, 1.0]), 3,
                              "KHR_materials_volume attenuationColor", src), 0.0, 1.0)
    # the draft's two spellings (exporters/gltf.py writes both): Babylon.js' Factor first
    key = "multiscatterColorFactor" if "multiscatterColorFactor" in scatter else "multiscatterColor"
    multiscatter = np.clip(_numbers(scatter.get(key, [0.0, 0.0, 0.0]), 3,
                                    f"KHR_materials_volume_scatter {key}", src), 0.0, 1.0)
    g = float(_numbers(scatter.get("scatterAnisotropy", 0.0), 1, "KHR_materials_volume_scatter scatterAnisotropy",
                       src)[0])
    with np.errstate(divide="ignore"):  # colour 0: an infinite extinction, clipped below
        sigma_t = np.clip(-np.log(colour) / (dist * mm_per_unit), EXTINCTION.low, COEFFICIENT.high)  # 1/mm
    rho = single_scatter_albedo(multiscatter)
    eta = float(src.ior or 1.5)
    return Material(f"{src.name} (KHR_materials_volume_scatter)", (1.0 - g) * rho * sigma_t, (1.0 - rho) * sigma_t,
                    eta, profile)


def assign_materials(scene: Scene, options: BakeOptions, mm_per_unit: float) -> Assignment:
    """Decide each material's scattering parameters.

    Order: the first ``options.materials`` pattern matching the material's name; else the
    material's own draft KHR_materials_volume_scatter with its KHR_materials_volume attenuation
    (`material_from_khr_volume_scatter`); else its KHR_materials_volume attenuation read as
    sssbake's fallback writes it (`material_from_khr_volume`); else ``options.material``. An
    sssbake output's ``SSSBAKE_subsurface`` material is not read: a re-bake takes the glTF
    extensions, as any other viewer does. Primitives with no material get a new one named
    ``sssbake_default`` with ``options.material``.

    Raises
    ------
    MaterialError
        When a rule names an unknown preset or impossible coefficients.
    """
    materials = list(scene.materials)
    meshes = scene.meshes
    if any(p.material is None for m in meshes for p in m.primitives):
        default_index = len(materials)
        materials.append(SourceMaterial(DEFAULT_MATERIAL_NAME, base_color_factor=(0.8, 0.8, 0.8, 1.0)))
        meshes = tuple(
            replace(m, primitives=tuple(p if p.material is not None else replace(p, material=default_index) for p in m.primitives))
            for m in meshes
        )
    used = sorted({p.material for m in meshes for p in m.primitives})
    out: dict[int, Material | None] = {}
    reasons: dict[int, str] = {}
    for i in used:
        src = materials[i]
        rule = next(((g, s) for g, s in options.materials if fnmatch.fnmatch(src.name.lower(), g.lower())), None)
        if rule is not None:
            out[i] = _spec_material(rule[1], src.name, options.profile)
            reasons[i] = f"material name matches rule {rule[0]!r}"
            continue
        khr = (material_from_khr_volume_scatter(src, mm_per_unit, options.profile)
               if src.volume and src.volume_scatter is not None else None)
        if khr is not None:
            out[i] = khr
            reasons[i] = "from the input's KHR_materials_volume_scatter (draft) and KHR_materials_volume attenuation"
            continue
        khr = material_from_khr_volume(src, mm_per_unit, options.profile) if src.volume else None
        if khr is not None:
            out[i] = khr
            reasons[i] = "from the input's KHR_materials_volume attenuation and base colour"
            continue
        out[i] = _spec_material(options.material, src.name, options.profile)
        reasons[i] = f"asset material {options.material!r}" if isinstance(options.material, str) else "asset material"
    return Assignment(replace(scene, meshes=meshes, materials=tuple(materials)), out, reasons)
