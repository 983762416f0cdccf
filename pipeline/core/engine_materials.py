"""Engine-native subsurface parameters of a measured material at an asset's scale.

A user with measured coefficients gets, per engine, the numbers its own subsurface model takes:

- ``openpbr_subsurface(material: Material, mm_per_unit: float) -> dict`` — OpenPBR Surface's
  ``subsurface_*`` inputs, in the asset's file units;
- `unreal_subsurface_profile` — Unreal Engine's Subsurface Profile asset (Burley);
- `unity_hdrp_diffusion_profile` — Unity HDRP's Diffusion Profile;
- `godot4_subsurface` — Godot 4's StandardMaterial3D ``subsurf_scatter_*`` properties;
- `khr_materials_volume_scatter` — Khronos's draft ``KHR_materials_volume_scatter`` glTF extension
  (with the ``KHR_materials_volume`` attenuation it redefines as extinction);
- `engine_materials` — all of them with the measured numbers, one record of ``<stem>.materials.json``.

All of them derive from the same two per-channel quantities of sssbake's profile, so an engine
shows the colour and the blur width the bake's own techniques do:

- the surface albedo A = R_d, the total diffuse reflectance of the flat semi-infinite medium under
  the material's profile model (`profile.total_reflectance`; the Monte Carlo table by default);
- the mean free path ℓ = 1/σ'_t (mm, `Material.mean_free_path_mm`). sssbake's coefficients are the
  reduced ones (σ'_s = σ_s (1 − g), the similarity relation), so ℓ is the mean free path of an
  isotropic medium and every anisotropy written is 0.

``material`` is a `materials.Material` (a bake's `ScatteringMaterial.material`); its per-mesh
escape and back gains describe the baked object, not the medium, and are dropped
(`Material.half_space`): an engine applies its own model to its own geometry. ``mm_per_unit`` is the
asset's scale, millimetres per file unit (> 0, finite).
"""

from __future__ import annotations

import math

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.profile import profile_for, total_reflectance


#: Godot 4's ``subsurf_scatter_transmittance_depth`` editor range starts here (``0.001,8,or_greater``).
GODOT_MIN_DEPTH = 0.001
#: Godot 4's project setting ``rendering/environment/subsurface_scattering/subsurface_scattering_scale``
#: (default 0.05 world units): the screen-space blur radius a ``subsurf_scatter_strength`` of 1 gives.
GODOT_SSS_SCALE = 0.05
#: Unreal encodes WorldUnitScale × 0.02 and the diffuse mean free path (mm) × 0.002 in [0, 1]
#: (ENC_WORLDUNITSCALE_IN_CM_TO_UNIT, ENC_DIFFUSEMEANFREEPATH_IN_MM_TO_UNIT,
#: BurleyNormalizedSSSCommon.ush): both top out at 50 cm.
UNREAL_MAX_CM = 50.0
#: The largest finite distance written where the physics gives none (no absorption: light is never
#: extinguished by depth): float32's largest is what the engines store, 1e30 stays clear of it.
FAR = 1e30


def surface_albedo(material: Material) -> np.ndarray:
    """(3,) float64 in [0, 1]: R_d, the share of light entering the flat medium that leaves it.

    The half-space medium's `profile.total_reflectance` under the material's profile model,
    clipped to [0, 1] (the Monte Carlo table's fit may overshoot 1 by rounding at α' = 1).
    """
    return np.clip(total_reflectance(profile_for(material.half_space)), 0.0, 1.0)


def _scale(mm_per_unit: float) -> float:
    """`mm_per_unit` checked: a finite number > 0."""
    value = float(mm_per_unit)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"mm_per_unit must be a finite number > 0, got {mm_per_unit!r}")
    return value


def openpbr_subsurface(material: Material, mm_per_unit: float) -> dict:
    """OpenPBR Surface's subsurface inputs for `material` on an asset of `mm_per_unit` mm per unit.

    OpenPBR Surface 1.1 (https://academysoftwarefoundation.github.io/OpenPBR/, "Subsurface"):
    ``subsurface_color`` is the albedo the subsurface lobe shows (the renderer inverts it to the
    medium's single-scattering albedo), and the per-channel mean free path is
    ``subsurface_radius × subsurface_radius_scale`` in scene units, with the phase function's
    ``subsurface_scatter_anisotropy`` g in [-1, 1]. So

        subsurface_color = R_d,   subsurface_radius = max_c ℓ_c / mm_per_unit,
        subsurface_radius_scale = ℓ / max_c ℓ_c,   subsurface_scatter_anisotropy = 0

    (the scale then lies in (0, 1], the form OpenPBR's defaults take), ``subsurface_weight`` = 1
    (the whole base is subsurface).

    Returns
    -------
    dict
        ``subsurface_weight`` (float), ``subsurface_color`` ((3,) list, linear),
        ``subsurface_radius`` (float, file units), ``subsurface_radius_scale`` ((3,) list),
        ``subsurface_scatter_anisotropy`` (float); all finite.
    """
    mfp = material.mean_free_path_mm / _scale(mm_per_unit)  # file units
    radius = float(mfp.max())
    return {
        "subsurface_weight": 1.0,
        "subsurface_color": surface_albedo(material).tolist(),
        "subsurface_radius": radius,
        "subsurface_radius_scale": (mfp / radius).tolist(),
        # reduced coefficients: the similarity relation has made the medium isotropic
        "subsurface_scatter_anisotropy": 0.0,
    }


def burley_s(albedo) -> np.ndarray:
    """Christensen & Burley 2015's scaling s(A) for the mean-free-path parameterisation.

    "Approximate Reflectance Profiles for Efficient Subsurface Scattering" (Pixar Technical Memo
    15-04), eq. 6 (perpendicular incidence, fitted to Monte Carlo): s(A) = 1.85 − A + 7 |A − 0.8|³,
    so that Burley's normalised diffusion R(r) = A s (e^(−s r/ℓ) + e^(−s r/(3ℓ))) / (8π ℓ r) has the
    shape distance d = ℓ / s(A). s > 0 for A in [0, 1] (its minimum, at A ≈ 1, is 0.906).
    """
    a = np.asarray(albedo, dtype=np.float64)
    return 1.85 - a + 7.0 * np.abs(a - 0.8) ** 3


def burley_shape_distance_mm(material: Material) -> np.ndarray:
    """(3,) float64, mm: Burley's shape distance d = ℓ / s(A) with A = `surface_albedo`, ℓ = 1/σ'_t."""
    return material.mean_free_path_mm / burley_s(surface_albedo(material))


def _colour_and_scale(values: np.ndarray) -> tuple[list, float]:
    """`values` (3,) > 0 as a colour in (0, 1] (each / the largest) and the largest."""
    top = float(values.max())
    return (values / top).tolist(), top


def unreal_subsurface_profile(material: Material, mm_per_unit: float) -> dict:
    """Unreal Engine 5's Subsurface Profile asset (``FSubsurfaceProfileStruct``, Burley normalised).

    Unreal's documentation of the struct
    (https://dev.epicgames.com/documentation/en-us/unreal-engine/API/Runtime/Engine/FSubsurfaceProfileStruct):
    ``SurfaceAlbedo`` "should match the base color", ``MeanFreePathColor`` "controls how far light
    goes into the subsurface in the Red, Green and Blue channel; it is scaled by Mean Free Path
    Distance", ``MeanFreePathDistance`` is "in world/unreal units (cm)", ``WorldUnitScale``
    "controls the scale of world/unreal units (cm)", and ``bEnableMeanFreePath`` switches the
    distance from Burley's diffuse mean free path to the mean free path, which Unreal converts
    itself. So, with ℓ in cm (mm / 10):

        SurfaceAlbedo = R_d,   MeanFreePathColor = ℓ / max ℓ,   MeanFreePathDistance = max ℓ [cm],
        WorldUnitScale = cm per Unreal unit of the imported asset = mm_per_unit / 1000

    (Unreal's glTF importer makes a file unit 100 Unreal units, so one of them is mm_per_unit / 100 mm).
    Unreal's encodings hold both distances up to 50 cm (`UNREAL_MAX_CM`); SurfaceAlbedo is clamped
    to [0.01, 1] by its editor; values clamped here are named in ``clamped``.
    ``burleyShapeDistanceCm`` is d = ℓ / s(A) (`burley_s`), what Burley's profile itself takes,
    for reference.
    """
    scale = _scale(mm_per_unit)
    albedo = surface_albedo(material)
    mfp_cm = material.mean_free_path_mm / 10.0
    colour, distance = _colour_and_scale(mfp_cm)
    unit_scale = scale / 1000.0
    clamped = []
    if distance > UNREAL_MAX_CM:
        distance, clamped = UNREAL_MAX_CM, clamped + ["meanFreePathDistanceCm"]
    if unit_scale > UNREAL_MAX_CM:
        unit_scale, clamped = UNREAL_MAX_CM, clamped + ["worldUnitScaleCm"]
    if np.any(albedo < 0.01):
        clamped.append("surfaceAlbedo")
    return {
        "surfaceAlbedo": np.clip(albedo, 0.01, 1.0).tolist(),
        "meanFreePathColor": colour,
        "meanFreePathDistanceCm": distance,
        "enableMeanFreePath": True,
        "enableBurley": True,
        "worldUnitScaleCm": unit_scale,
        "burleyShapeDistanceCm": (burley_shape_distance_mm(material) / 10.0).tolist(),
        "ior": material.eta,
        "clamped": clamped,
    }


def unity_hdrp_diffusion_profile(material: Material, mm_per_unit: float,
                                 thickness_max_mm: float | None = None) -> dict:
    """Unity HDRP's Diffusion Profile asset (Burley normalised diffusion).

    HDRP's manual, "Diffusion Profile"
    (https://docs.unity3d.com/Packages/com.unity.render-pipelines.high-definition@14.0/manual/Diffusion-Profile.html):
    the Scattering Color "defines the shape of the profile" and its Multiplier "how far light travels
    below the surface", the filter radius being in millimetres at World Scale 1; World Scale is the
    size of a Unity unit ("by default 1 Unity unit is 1 meter"); Thickness Remap maps the thickness
    map's [0, 1] to millimetres; Transmission Tint multiplies the transmitted light. HDRP's profile is
    Burley's with the shape distance d per channel, so

        scatteringColor = d / max d,   multiplier = max d [mm],   d = ℓ / s(A) (`burley_s`),
        worldScale = mm_per_unit / 1000 [m per unit: glTF importers keep a file unit one Unity unit],
        thicknessRemapMm = [0, thickness_max_mm],   transmissionTint = (1, 1, 1)

    (the tint stays white: the profile already colours what it transmits).

    Parameters
    ----------
    thickness_max_mm : float or None
        The largest baked thickness, mm: the thickness texture holds thickness / this. None (no
        thickness baked): ``thicknessRemapMm`` is null.
    """
    scale = _scale(mm_per_unit)
    colour, multiplier = _colour_and_scale(burley_shape_distance_mm(material))
    remap = None
    if thickness_max_mm is not None:
        remap = [0.0, min(float(thickness_max_mm), FAR)]
    return {
        "scatteringColor": colour,
        "multiplierMm": multiplier,
        "worldScaleM": scale / 1000.0,
        "thicknessRemapMm": remap,
        "transmissionTint": [1.0, 1.0, 1.0],
        "ior": material.eta,
        "clamped": [],
    }


def godot4_subsurface(material: Material, mm_per_unit: float) -> dict:
    """Godot 4's StandardMaterial3D subsurface scattering properties (world units = file units).

    Godot's class reference, BaseMaterial3D
    (https://docs.godotengine.org/en/stable/classes/class_basematerial3d.html):
    ``subsurf_scatter_strength`` (0-1) is the screen-space blur, whose size "is also controlled by
    ProjectSettings.rendering/environment/subsurface_scattering/subsurface_scattering_scale"
    (`GODOT_SSS_SCALE`, world units); ``subsurf_scatter_transmittance_depth`` (world units, editor
    range from 0.001) and ``_color`` shape the light let through, which Godot's forward shader
    weights by exp(−(8.25 z / depth)²) over the shadow-map thickness z; ``_boost`` (0-1) lets it
    through lit faces too; ``subsurf_scatter_transmittance_texture`` scales its intensity (a mask,
    not a thickness: sssbake's thickness texture does not fit it and is not named). So, with
    σ_tr the diffusion extinction (1/mm) and c* the most penetrating channel:

        strength = clamp(max d / mm_per_unit / GODOT_SSS_SCALE, 0, 1)   (d: `burley_shape_distance_mm`)
        depth = 8.25 / σ_tr,c* / mm_per_unit   (Godot's 1/e thickness, depth/8.25, is the diffusion's, 1/σ_tr)
        transmittanceColor_c = exp(1 − σ_tr,c / σ_tr,c*)   (each channel's diffusion transmittance there, × e)
        boost = 0   (a flat medium lets nothing through its lit side)

    Without absorption in some channel (σ_tr = 0) nothing limits the depth: it is `FAR` and the
    colour 1 where σ_tr = 0. ``depth`` is clamped up to `GODOT_MIN_DEPTH`; clamps are named in
    ``clamped``.
    """
    scale = _scale(mm_per_unit)
    clamped = []
    shape = float(burley_shape_distance_mm(material).max()) / scale
    strength = shape / GODOT_SSS_SCALE
    if strength > 1.0:
        strength, clamped = 1.0, clamped + ["subsurfScatterStrength"]
    sigma_tr = material.half_space.sigma_tr  # 1/mm
    least = float(sigma_tr.min())
    if least > 0.0:
        depth = 8.25 / least / scale
        colour = np.exp(1.0 - sigma_tr / least)
    else:
        depth = FAR
        colour = np.where(sigma_tr > 0.0, 0.0, 1.0)  # any absorption is infinitely stronger
    if depth > FAR:
        depth, clamped = FAR, clamped + ["subsurfScatterTransmittanceDepth"]
    if depth < GODOT_MIN_DEPTH:
        depth, clamped = GODOT_MIN_DEPTH, clamped + ["subsurfScatterTransmittanceDepth"]
    return {
        "albedoColor": surface_albedo(material).tolist(),
        "subsurfScatterEnabled": True,
        "subsurfScatterSkinMode": False,
        "subsurfScatterStrength": strength,
        "subsurfScatterTransmittanceEnabled": True,
        "subsurfScatterTransmittanceColor": colour.tolist(),
        "subsurfScatterTransmittanceDepth": depth,
        "subsurfScatterTransmittanceBoost": 0.0,
        "subsurfaceScatteringScaleAssumed": GODOT_SSS_SCALE,
        "clamped": clamped,
    }


#: The Kulla & Conty 2017 fit that KHR_materials_volume_scatter maps the multi-scatter albedo
#: ρ_ms to the single-scatter albedo with: ρ_ss = 1 − (P + Q ρ_ms − sqrt(R + S ρ_ms + T ρ_ms²))².
_KC = (4.09712, 4.20863, 9.59217, 41.6808, 17.7126)


def single_scatter_albedo(multiscatter) -> np.ndarray:
    """ρ_ss of a multi-scatter albedo ρ_ms (array, [0, 1]) under KHR_materials_volume_scatter's fit.

    The draft's "Multi-Scatter Albedo" section (https://github.com/KhronosGroup/glTF/blob/main/
    extensions/2.0/Khronos/KHR_materials_volume_scatter/README.md), after Kulla & Conty 2017:
    ρ_ss = 1 − (4.09712 + 4.20863 ρ_ms − sqrt(9.59217 + 41.6808 ρ_ms + 17.7126 ρ_ms²))².
    6e-6 at ρ_ms = 0, increasing to its peak 1 − O(1e-11) at ρ_ms ≈ 0.99999 (where the square's
    base crosses 0), then flat to ρ_ms = 1.
    """
    p, q, r, s, t = _KC
    m = np.asarray(multiscatter, dtype=np.float64)
    return 1.0 - (p + q * m - np.sqrt(r + s * m + t * m * m)) ** 2


def multiscatter_albedo(single) -> np.ndarray:
    """The inverse of `single_scatter_albedo`: ρ_ms in [0, 1] of each ρ_ss (array).

    Outside the fit's range (ρ_ss below its value at 0 or above its value at 1) ρ_ms is clamped to 0
    or 1. Bisection: the fit is increasing, and its closed-form inverse, a quadratic whose leading
    coefficient (4.20863² − 17.7126 = −3.5e-5) nearly vanishes, loses digits.
    """
    target = np.asarray(single, dtype=np.float64)
    lo, hi = np.zeros_like(target), np.ones_like(target)
    for _ in range(64):  # 2^-64 < float64's resolution on [0, 1]
        mid = 0.5 * (lo + hi)
        below = single_scatter_albedo(mid) < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def khr_materials_volume_scatter(material: Material, mm_per_unit: float) -> dict:
    """The draft KHR_materials_volume_scatter extension, with the KHR_materials_volume attenuation it needs.

    The draft (see `single_scatter_albedo`) redefines KHR_materials_volume's attenuation as the
    extinction σ_t = σ_a + σ_s = −ln(attenuationColor) / attenuationDistance, the single-scatter
    albedo ρ_ss = σ_s / σ_t coming from ``multiscatterColor`` through its fit, and the
    Henyey-Greenstein ``scatterAnisotropy`` g. A renderer that implements it then holds sssbake's
    medium exactly:

        ρ_ss = α' = σ'_s / σ'_t  →  multiscatterColor = `multiscatter_albedo`(α'),
        attenuationDistance = max ℓ / mm_per_unit [file units],
        attenuationColor = exp(−σ'_t · mm_per_unit · attenuationDistance) = exp(−ℓ_max / ℓ) ∈ [1/e^k, 1/e],
        scatterAnisotropy = 0 (reduced coefficients).

    ``multiscatterColor`` is therefore not R_d: the fit is the albedo a diffuse render shows, not
    sssbake's profile with its dielectric boundary; ``surfaceAlbedo`` gives R_d for comparison.
    The colour's exponent ℓ_max/ℓ ≤ σ'_t,max/σ'_t,min stays finite (σ'_t ≥ 1e-6 /mm, `EXTINCTION`);
    it can underflow to 0 (below 1e-308), which the draft reads as an infinite extinction.
    """
    scale = _scale(mm_per_unit)
    mfp = material.mean_free_path_mm
    albedo = material.albedo_prime
    return {
        "multiscatterColor": multiscatter_albedo(albedo).tolist(),
        "scatterAnisotropy": 0.0,
        "attenuationColor": np.exp(-mfp.max() / mfp).tolist(),
        "attenuationDistance": float(mfp.max()) / scale,
        "singleScatterAlbedo": albedo.tolist(),
        "surfaceAlbedo": surface_albedo(material).tolist(),
        "clamped": [],
    }


def measured(material: Material) -> dict:
    """The material's own numbers, units in the keys (σ in 1/mm, reduced scattering as sssbake keeps it)."""
    return {
        "albedo": surface_albedo(material).tolist(),
        "meanFreePathMm": material.mean_free_path_mm.tolist(),
        "eta": material.eta,
        "sigmaAPerMm": list(material.sigma_a),
        "sigmaSPrimePerMm": list(material.sigma_s_prime),
        "singleScatterAlbedo": material.albedo_prime.tolist(),
        "profile": material.profile,
    }


def engine_materials(material: Material, mm_per_unit: float, thickness_max_mm: float | None = None) -> dict:
    """One ``materials`` record of ``<stem>.materials.json``: `measured` and every engine's numbers.

    Every number is finite (`check_finite` in the writer asserts it; see each function's clamps).
    """
    return {
        "measured": measured(material),
        "unreal": unreal_subsurface_profile(material, mm_per_unit),
        "unityHdrp": unity_hdrp_diffusion_profile(material, mm_per_unit, thickness_max_mm),
        "godot4": godot4_subsurface(material, mm_per_unit),
        "openpbr": openpbr_subsurface(material, mm_per_unit),
        "khrMaterialsVolumeScatter": khr_materials_volume_scatter(material, mm_per_unit),
    }
