"""``sssbake verify FILE --reference volpath``: an export against physics, not against our own model.

The ground truth is Mitsuba 3's volumetric path tracer (``volpath``) on the file's geometry: a
smooth ``dielectric`` boundary of the material's η around a homogeneous medium with σ_s = σ'_s,
σ_a and an isotropic phase function (the similarity relation the reduced coefficients assume), per
channel in 1/mm times the file's millimetres per world unit. Each colour channel is rendered alone
in a mono variant (`VARIANT`): an RGB medium goes through hero wavelengths and is far noisier.

Light: a smooth dielectric lit by a ``directional`` emitter renders black in volpath (no path
through a delta boundary can connect to a delta light), so the truth is lit by an environment
lobe around verify's light direction l, L(ω) = L0 max(0, ω·l)^n (`Lobe`, n = 4, L0 = (n+2)/(2π):
unit irradiance on a surface facing l, as verify's directional light). sssbake's side is linear in
the light, so it sees the same lobe by quadrature: a weighted sum of verify's directional renders
over `Lobe.quadrature`'s directions (`lobe_image`).

Specular: sssbake's runtimes draw the scattered light alone (verify renders without the surface's
specular term), so the boundary's mirror reflection is subtracted from the truth and reported
apart (``specular_share``). It is measured by rendering the same scene with a black, dense
interior (albedo 0: every path that enters dies), with the same seeds, so both renders sample the
same paths up to the first refraction inward and the difference holds exactly the light that
entered the medium.

Noise: two independent halves (two seeds); the truth is their mean T = (A + B)/2 and its noise
floor, the relative RMSE a perfect image would score, is ||A - B|| / (2 ||T||) over the object's
pixels. A measured relative RMSE r contains it: sqrt(r² - floor²) is the error without it.

The truth is cached by content (`truth_key`: the meshes' bytes, materials, scales, light, camera,
samples, Mitsuba's version) in the bake's stage cache (`bake.cache.StageCache`).
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_erosion

from sssbake.pipeline.bake.cache import StageCache, stage_key
from sssbake.pipeline.core.errors import VerifyError
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.profile import profile_for, total_reflectance
from sssbake.pipeline.core.visibility import direction_visibility
from sssbake.pipeline.render.image_metrics import (
    best_fit_scale,
    rmse,
    shared_exposure,
    write_comparison_png,
    write_difference_png,
)
from sssbake.pipeline.render.renderer import DEFAULT_LIGHT, Camera, Renderer, RenderLight, fit_camera
from sssbake.pipeline.techniques.registry import BY_NAME, NAMES
from sssbake.pipeline.techniques.technique import VerifyUnit
from sssbake.pipeline.verify.fallback_radiance import FallbackLook
from sssbake.pipeline.verify.verify import draw_instances, lambert_q, light_direction, unit_surface
from sssbake.pipeline.verify.volpath_measures import block_reading, measure, pixel_reading, vertex_reading

#: Mitsuba variant of the truth: one channel at a time (LLVM: vectorised on the CPU).
VARIANT = "llvm_ad_mono"
#: Debian's LLVM 19 (``apt-get install libllvm19``); older LLVMs on a machine abort Dr.Jit.
DEBIAN_LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
INSTALL_HINT = ("verify --reference volpath needs Mitsuba 3: pip install 'sssbake[physics]' "
                "(on Debian also: apt-get install libllvm19)")
#: Bump when the truth's scene changes for the same inputs (part of its cache key).
TRUTH_VERSION = 1
#: The defaults of ``--reference volpath``: image side and samples per pixel per channel (both halves).
VOLPATH_SIZE = 128
VOLPATH_SPP = 256
#: Rows of the environment map (twice as many columns): Mitsuba's bilinear lookups then stay within
#: 0.4 % of the cos⁴ lobe's peak (0.05 % rms over the sphere).
ENVMAP_HEIGHT = 512
#: Seeds of the two halves (each pass adds 2 to both, so no two passes share one).
SEEDS = (1, 2)
#: Camera samples per render call (pixels × samples): bounds Dr.Jit's per-lane memory.
LANES_PER_PASS = 1 << 22
#: Extinction of the specular render's interior relative to the medium's: nothing crosses it.
BLACK_DENSITY = 1e3
#: volpath's Russian roulette caps survival at 0.95, which biases media of albedo near 1 (marble's
#: is 0.999): start it never; paths end when they leave.
NO_ROULETTE = 1 << 30


class VolpathUnavailable(VerifyError):
    """Mitsuba 3 (or the LLVM its variant needs) is missing: `INSTALL_HINT`."""


def prefer_debian_llvm() -> None:
    """Point Dr.Jit at Debian's LLVM 19 unless the caller chose one (``DRJIT_LIBLLVM_PATH``): it
    loads whichever libLLVM it finds first when ``drjit`` is imported, and older ones abort it."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.isfile(DEBIAN_LIBLLVM):
        os.environ["DRJIT_LIBLLVM_PATH"] = DEBIAN_LIBLLVM


def load_mitsuba():
    """Mitsuba 3 in `VARIANT` (`prefer_debian_llvm` first), or VolpathUnavailable with `INSTALL_HINT`."""
    prefer_debian_llvm()
    try:
        import mitsuba as mi

        mi.set_variant(VARIANT)
    except ImportError as e:  # no package, or no usable libLLVM (Dr.Jit reports that as ImportError)
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise VolpathUnavailable(f"{INSTALL_HINT} ({reason[:160]})") from None
    mi.set_log_level(mi.LogLevel.Error)
    return mi


@dataclass(frozen=True)
class Lobe:
    """The truth's light: environment radiance L(ω) = L0 max(0, ω·l)^n, L0 = (n+2)/(2π), so that
    a surface facing l receives unit irradiance (verify's directional light gives the same).

    Attributes
    ----------
    direction : (3,) float
        Unit world direction l towards the lobe's centre.
    exponent : int
        n.
    """

    direction: tuple[float, float, float]
    exponent: int = 4

    @property
    def peak(self) -> float:
        """L0: ∫ L0 μ^n μ dω over the hemisphere around l is 2π L0/(n+2) = 1."""
        return (self.exponent + 2) / (2.0 * np.pi)

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """(...,) L(ω) of unit world `directions` (..., 3)."""
        return self.peak * np.clip(directions @ np.asarray(self.direction), 0.0, None) ** self.exponent

    def quadrature(self, rings: int = 6, azimuths: int = 8) -> tuple[np.ndarray, np.ndarray]:
        """Directions and weights with Σ_k w_k f(ω_k) ≈ ∫ L(ω) f(ω) dω: each w_k is the irradiance
        a directional light from ω_k stands for.

        With t = μ^(n+1) (μ = ω·l) the lobe's measure L0 μ^n dμ dφ is uniform in (t, φ), so the
        rule splits t into `rings` equal steps and φ into `azimuths` (every other ring turned by
        half a step), all of one weight L0 2π / ((n+1) K). A ring's μ is μ's mean over its step,
        so the rule is exact for the irradiance of surfaces the whole lobe lights (n·ω is linear
        in μ, cos φ and sin φ, and the azimuths' sums of cos φ and sin φ vanish).

        Returns
        -------
        directions : (K, 3) float64
            Unit world directions, K = rings · azimuths.
        weights : (K,) float64
            Σ w_k = (n+2)/(n+1), Σ w_k μ_k = 1.
        """
        l = np.asarray(self.direction, dtype=np.float64)
        u = np.cross(l, [1.0, 0.0, 0.0] if abs(l[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(l, u)
        power = (self.exponent + 2) / (self.exponent + 1)
        edges = np.linspace(0.0, 1.0, rings + 1)
        mu = np.diff(edges**power) * rings / power  # the mean of t^(1/(n+1)) over each step
        phi = 2.0 * np.pi * (np.arange(azimuths)[None, :] + 0.5 * (np.arange(rings)[:, None] % 2)) / azimuths
        sin = np.sqrt(1.0 - mu**2)[:, None]
        across = np.cos(phi)[..., None] * u + np.sin(phi)[..., None] * v
        directions = mu[:, None, None] * l + sin[..., None] * across
        count = rings * azimuths
        weights = np.full(count, self.peak * 2.0 * np.pi / ((self.exponent + 1) * count))
        return directions.reshape(count, 3), weights

    def envmap(self, height: int = ENVMAP_HEIGHT) -> np.ndarray:
        """(height, 2 height) float32 L at the texel centres of Mitsuba's ``envmap`` layout: texel
        (u, v) looks along (sin 2πu sin πv, cos πv, -cos 2πu sin πv)."""
        theta = np.pi * (np.arange(height) + 0.5) / height
        phi = 2.0 * np.pi * (np.arange(2 * height) + 0.5) / (2 * height)
        st = np.sin(theta)[:, None]
        directions = np.stack([np.sin(phi)[None, :] * st, np.cos(theta)[:, None] * np.ones_like(phi)[None, :],
                               -np.cos(phi)[None, :] * st], axis=-1)
        return self.radiance(directions).astype(np.float32)


@dataclass(frozen=True, eq=False)
class Body:
    """One closed object of the truth, in world units.

    Attributes
    ----------
    positions : (n, 3) float64
    normals : (n, 3) float64
        Unit vertex normals (the dielectric's shading normals, as the runtimes shade).
    faces : (m, 3) int64
        Wound so that the geometric normals point out (Mitsuba tells inside from outside by them).
    material : Material
    mm_per_unit : float
        Millimetres per world unit.
    """

    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    material: Material
    mm_per_unit: float


@dataclass(frozen=True)
class View:
    """A pinhole camera, world units.

    Attributes
    ----------
    eye, forward, up : (3,) float
        Position, unit viewing direction, unit up (orthogonal to forward).
    fov_degrees : float
        Vertical field of view.
    near, far : float
        Clip distances along `forward`.
    size : int
        Square image side in pixels.
    """

    eye: tuple[float, float, float]
    forward: tuple[float, float, float]
    up: tuple[float, float, float]
    fov_degrees: float
    near: float
    far: float
    size: int

    @classmethod
    def of(cls, camera: Camera, size: int) -> View:
        """verify's `camera` (a GL view-projection) as a pinhole: the points it projects to the
        image's centre, top edge and near and far planes give the axes, the field of view and the
        clip distances."""
        inverse = np.linalg.inv(camera.view_projection)

        def world(x: float, y: float, z: float) -> np.ndarray:
            p = inverse @ np.array([x, y, z, 1.0])
            return p[:3] / p[3]

        eye = np.asarray(camera.eye, dtype=np.float64)
        centre, top = world(0.0, 0.0, 0.0), world(0.0, 1.0, 0.0)
        forward = (centre - eye) / np.linalg.norm(centre - eye)
        up = (top - centre) / np.linalg.norm(top - centre)
        fov = 2.0 * np.degrees(np.arctan(np.linalg.norm(top - centre) / np.linalg.norm(centre - eye)))
        near = float(np.dot(world(0.0, 0.0, -1.0) - eye, forward))
        far = float(np.dot(world(0.0, 0.0, 1.0) - eye, forward))
        return cls(tuple(eye), tuple(forward), tuple(up), float(fov), near, far, int(size))


@dataclass(frozen=True, eq=False)
class Truth:
    """volpath's images of the scattered light (the mirror reflection taken out).

    Attributes
    ----------
    halves : (2, H, W, 3) float64
        The two independent halves (seeds `SEEDS`), each of spp/2 samples per pixel and channel.
    specular : (H, W, 3) float64
        The boundary's mirror reflection that was taken out (both halves' mean).
    seconds : float
        Mitsuba's wall time when it was rendered (not when read from the cache).
    """

    halves: np.ndarray
    specular: np.ndarray
    seconds: float

    @property
    def image(self) -> np.ndarray:
        """(H, W, 3) float64 the halves' mean."""
        return self.halves.mean(axis=0)


def truth_key(bodies: list[Body], view: View, lobe: Lobe, spp: int, mitsuba_version: str) -> str:
    """The truth's stage-cache key: the bodies' geometry bytes (the upstream hash), their
    materials' coefficients (not their names or profile models: the truth does not read them) and
    scales, the light, the camera, the samples and Mitsuba's version."""
    digest = hashlib.sha256()
    for body in bodies:
        for array in (body.positions.astype(np.float64), body.normals.astype(np.float64), body.faces.astype(np.int64)):
            digest.update(np.ascontiguousarray(array).tobytes())
            digest.update(str(array.shape).encode())
    media = [{"sigma_s_prime": body.material.sigma_s_prime, "sigma_a": body.material.sigma_a,
              "eta": body.material.eta, "mm_per_unit": body.mm_per_unit} for body in bodies]
    params = {"media": media, "view": view, "lobe": lobe, "spp": spp, "seeds": SEEDS, "envmap": ENVMAP_HEIGHT,
              "mitsuba": mitsuba_version, "variant": VARIANT}
    return stage_key(digest.hexdigest(), "volpath", TRUTH_VERSION, params)


def render_truth(bodies: list[Body], view: View, lobe: Lobe, spp: int = VOLPATH_SPP,
                 cache: StageCache | None = None) -> tuple[Truth, bool]:
    """volpath's images of `bodies` lit by `lobe`, from the `cache` when it holds them.

    Parameters
    ----------
    spp : int
        Samples per pixel and channel, both halves together (even, >= 2).

    Returns
    -------
    truth : Truth
    cached : bool
        Whether it came from the cache.
    """
    if spp < 2 or spp % 2:
        raise VerifyError(f"verify: volpath needs an even number of samples per pixel >= 2, got {spp}")
    mi = load_mitsuba()
    cache = cache if cache is not None else StageCache(None)
    key = truth_key(bodies, view, lobe, spp, mi.__version__)
    found = cache.get(key)
    if isinstance(found, Truth):
        return found, True
    t = time.perf_counter()
    half = spp // 2
    per_pass = max(1, min(half, LANES_PER_PASS // (view.size * view.size)))
    halves = np.zeros((2, view.size, view.size, 3))
    specular = np.zeros((view.size, view.size, 3))
    bitmap = mi.Bitmap(lobe.envmap()[..., None])
    for c in range(3):
        full, black = (_scene(mi, bodies, view, bitmap, c, dark) for dark in (False, True))
        for h, seed in enumerate(SEEDS):
            for start in range(0, half, per_pass):
                count = min(per_pass, half - start)
                # The same seed in both scenes: their paths agree up to the first refraction inward.
                seeded = dict(seed=seed + 2 * (start // per_pass), spp=count)
                lit = np.array(mi.render(full, **seeded), dtype=np.float64)[..., 0]
                mirror = np.array(mi.render(black, **seeded), dtype=np.float64)[..., 0]
                halves[h, ..., c] += (lit - mirror) * (count / half)
                specular[..., c] += mirror * (count / spp)
    if not (np.all(np.isfinite(halves)) and np.all(np.isfinite(specular))):
        raise VerifyError("verify: volpath returned non-finite pixels")
    truth = Truth(halves, specular, time.perf_counter() - t)
    cache.put(key, truth)
    return truth, False


def _scene(mi, bodies: list[Body], view: View, bitmap, channel: int, dark: bool):
    """Mitsuba's scene of `bodies` for one colour `channel`: the medium's (`dark` False) or a
    black one of `BLACK_DENSITY` times its extinction that only the mirror reflection leaves."""
    eye, forward = np.asarray(view.eye), np.asarray(view.forward)
    scene = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": NO_ROULETTE},
        "sensor": {
            "type": "perspective", "fov": view.fov_degrees, "fov_axis": "y", "near_clip": view.near,
            "far_clip": view.far,
            "to_world": mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=(eye + forward).tolist(),
                                                       up=list(view.up)),
            "film": {"type": "hdrfilm", "width": view.size, "height": view.size, "pixel_format": "luminance",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "independent"},
        },
        "light": {"type": "envmap", "bitmap": bitmap},
    }
    for i, body in enumerate(bodies):
        m = body.material
        # σ_t = 1 and the coefficient in `scale`: a sigma_t above 1 as a spectrum is refused.
        extinction = m.sigma_t_prime[channel] * body.mm_per_unit * (BLACK_DENSITY if dark else 1.0)
        props = mi.Properties()
        props["bsdf"] = mi.load_dict({"type": "dielectric", "int_ior": float(m.eta), "ext_ior": 1.0})
        props["interior"] = mi.load_dict({"type": "homogeneous", "sigma_t": 1.0, "scale": float(extinction),
                                          "albedo": 0.0 if dark else float(m.albedo_prime[channel]),
                                          "phase": {"type": "isotropic"}})
        mesh = mi.Mesh(f"body{i}", len(body.positions), len(body.faces), props=props, has_vertex_normals=True)
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(np.ravel(body.positions).astype(np.float32))
        params["vertex_normals"] = mi.Float(np.ravel(body.normals).astype(np.float32))
        params["faces"] = mi.UInt32(np.ravel(body.faces).astype(np.uint32))
        params.update()
        scene[f"body{i}"] = mesh
    return mi.load_dict(scene)


def lobe_image(renderer: Renderer, items: list[dict], camera: Camera, directions: np.ndarray,
               weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`items` drawn under a lobe: Σ_k w_k · (the image under a directional light from ω_k).

    Items whose radiance was computed per vertex (``q``: the lobe's light already in it) are drawn
    once; the light then only drives the surface terms, which verify leaves off.

    Parameters
    ----------
    directions : (K, 3) float64
        Unit world directions towards the lights.
    weights : (K,) float64
        Their irradiances.

    Returns
    -------
    image : (H, W, 3) float64
    coverage : (H, W) bool
    """
    if all("q" in item for item in items):
        image, coverage = renderer.render(items, camera, RenderLight(False, tuple(directions[0]), 1.0))
        return image.astype(np.float64), coverage
    total = None
    for direction, weight in zip(directions, weights):
        image, coverage = renderer.render(items, camera, RenderLight(False, tuple(direction), 1.0))
        total = weight * image.astype(np.float64) + (0.0 if total is None else total)
    return total, coverage


def lobe_q(field: np.ndarray, towards: np.ndarray, weight: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """(n, 3) Lambert radiance albedo · E / π of unit normals `field` (n, 3) under a lobe, E the
    irradiance `lambert_q` sums over its K directions `towards` (K, 3), `weight` (n, K) each
    direction's visible irradiance per vertex, `albedo` (3,)."""
    irradiance = sum(lambert_q(field, towards[k : k + 1], weight[:, k]) for k in range(len(towards)))
    return irradiance * np.asarray(albedo) / np.pi


def verify_volpath(path: str | os.PathLike, technique: str = "prt", light_dir=DEFAULT_LIGHT,
                   size: int = VOLPATH_SIZE, spp: int = VOLPATH_SPP, out_dir: str | os.PathLike | None = None,
                   cache_dir: str | os.PathLike | None = None, lpv_steps: int | None = None) -> dict:
    """`technique`'s runtime, plain Lambert and best-fit Lambert against volpath's ground truth,
    all under verify's camera and a lobe around `light_dir` (see the module docstring).

    Parameters
    ----------
    light_dir : (3,) float
        World direction towards the lobe's centre.
    size : int
        Image side in pixels.
    spp : int
        The truth's samples per pixel and channel, both halves together.
    out_dir : path, optional
        Where the PNGs go (default: next to the file).
    cache_dir : path, optional
        The truth's cache folder (default: ``.sssbake-cache`` next to the file, the bake's default).
    lpv_steps : int, optional
        lpv: propagation steps per frame.

    Returns
    -------
    dict
        ``technique``, ``reference`` ("volpath"), ``light_dir``, ``lobe_exponent``,
        ``lobe_directions`` (K of the quadrature), ``specular`` (how the mirror reflection is
        handled), ``specular_share`` (its share of the object's light in volpath's image),
        ``rmse_relative`` (||image - truth|| / ||truth|| over the object's pixels × RGB),
        ``technique_scale`` (3,) (per-channel least-squares factor from the technique to the
        truth: above 1, too dark), ``rmse_relative_fitted`` (the technique times it),
        ``lambert_albedo`` (per material name, (3,): its profile's total reflectance),
        ``rmse_relative_lambert`` (plain Lambert of that albedo), ``lambert_scale`` (3,) and
        ``rmse_relative_lambert_fitted``, ``rmse_relative_fallback`` (what a glTF viewer draws of the
        standard fallback material, `fallback_radiance`; absent when its base colour is a texture),
        ``noise_floor`` (the truth's own relative noise: ||A - B|| / (2 ||T||) of its halves A, B
        and mean T), ``rmse_relative_denoised`` (each error less the floor in quadrature,
        sqrt(max(r² - floor², 0)), by its key), ``measures`` (the same errors read per block of
        pixels and per visible vertex, `volpath_measures.measure` by ``block`` and ``vertex``, each
        with its own noise floor), ``rmse_object`` and
        ``rmse_object_lambert`` (verify's [0, 1] image RMSE against the truth), ``exposure``,
        ``pixels`` (object pixels compared), ``spp``, ``image_size``, ``mitsuba`` (version),
        ``truth_seconds``, ``truth_cached``, ``pngs`` (``comparison``: truth | technique |
        Lambert | fitted Lambert, ``difference``).
    """
    mi = load_mitsuba()
    if technique not in NAMES:
        raise VerifyError(f"verify: technique must be one of {list(NAMES)}, got {technique!r}")
    hooks = BY_NAME[technique]
    path = Path(path)
    lobe = Lobe(tuple(light_direction(light_dir)))
    directions, weights = lobe.quadrature()
    data = hooks.read(path)
    file, scene, instances = draw_instances(path, technique, data)
    bodies, items, lambert_items, fallback_items, albedos = [], [], [], [], {}
    runtime, memo = {"lpv_steps": lpv_steps}, {}
    for mesh, unit, world in instances:
        prim, material, mm, surface, weld = unit_surface(file, scene, mesh, unit)
        linear = world[:3, :3]
        scale = abs(float(np.linalg.det(linear))) ** (1.0 / 3.0)
        if not np.allclose(linear.T @ linear, scale**2 * np.eye(3), rtol=1e-6, atol=1e-9 * scale**2):
            raise VerifyError(f"verify: {path}: mesh {mesh} is scaled unevenly; volpath needs one mm per unit "
                              "in every direction")
        bodies.append(_body(path, mesh, surface, world, material, mm / scale))
        local = np.linalg.solve(linear, directions.T).T
        local /= np.linalg.norm(local, axis=1, keepdims=True)
        visible = direction_visibility(surface.positions, surface.faces, surface.normals, local)[weld]
        base = dict(positions=prim.positions, normals=prim.normals, faces=prim.faces, model=world, eta=material.eta)
        # plain Lambert is the half-space's R_tot: the escape gain is the profile techniques' (docs/fidelity.md)
        half_space = material.half_space
        albedo = albedos.setdefault(material.name, total_reflectance(profile_for(half_space)))
        # Here lambert_q is the plain Lambert radiance of the profile's total reflectance, not verify's
        # grey cosine: spectral's runtime is the plain Lambert shader, which a viewer draws with
        # the fallback's base colour, so its unscaled figure means what it ships.
        at = VerifyUnit(mesh, tuple(unit), prim, surface, weld, mm, material, file.extension(file.gltf.meshes[mesh]),
                        base, partial(lobe_q, towards=local, weight=visible * weights, albedo=albedo))
        if hooks.reference_item(path, at, data, runtime, memo) is not None:
            raise VerifyError(f"verify: {path}: mesh {mesh}'s {technique} medium is not homogeneous; volpath models "
                              "the material's homogeneous medium")
        items.append(hooks.verify_items(at, data, runtime)[0])
        # η = 1: no exit Fresnel on the q draw, the plain Lambert radiance itself.
        lambert_items.append({**base, "eta": 1.0, "q": at.lambert_q(prim.normals)})
        look = FallbackLook.of(file.gltf.materials[scene.meshes[mesh].primitives[unit[0]].material])
        fallback_items.append(None if look is None else
                              {**base, "eta": 1.0, "q": look.radiance(prim.normals, local, weights, visible)})

    renderer = Renderer((size, size))
    camera = fit_camera(np.concatenate([(it["model"][:3, :3] @ it["positions"].T).T + it["model"][:3, 3]
                                        for it in items]))
    image, covered = lobe_image(renderer, items, camera, directions, weights)
    lambert, lambert_covered = lobe_image(renderer, lambert_items, camera, directions, weights)
    # A textured fallback's look is per texel, which a vertex q cannot draw: no fallback figure.
    fallback = None if None in fallback_items else lobe_image(renderer, fallback_items, camera, directions, weights)[0]
    truth, cached = render_truth(bodies, View.of(camera, size), lobe, spp, StageCache(
        Path(cache_dir) if cache_dir is not None else path.parent / ".sssbake-cache"))
    # Silhouette pixels are part background in volpath's pixel-averaged image: compare inside them.
    mask = binary_erosion(covered & lambert_covered)
    if not mask.any():
        raise VerifyError(f"verify: {path}: the object covers no whole pixel at {size}²; raise --size")
    reference = truth.image
    technique_scale = best_fit_scale(image, reference, mask)
    lambert_scale = best_fit_scale(lambert, reference, mask)
    if not np.linalg.norm(reference[mask]) > 0:
        raise VerifyError(f"verify: {path}: volpath's image of the object is black (the lobe lights nothing in view)")
    compared = {"rmse_relative": image, "rmse_relative_fitted": image * technique_scale,
                "rmse_relative_lambert": lambert, "rmse_relative_lambert_fitted": lambert * lambert_scale}
    if fallback is not None:
        compared["rmse_relative_fallback"] = fallback
    pixels = measure(pixel_reading(mask), compared, truth.halves)
    readings = [block_reading(mask), vertex_reading([(b.positions, b.faces, b.normals) for b in bodies], camera, mask)]
    measures = {r.name: measure(r, compared, truth.halves) for r in readings}
    shown = np.where(covered[..., None], reference, 0.0)  # volpath's background is the lobe itself
    exposure = shared_exposure(shown, mask)
    out_dir = Path(out_dir) if out_dir is not None else path.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{path.stem}.verify.{technique}.volpath"
    pngs = {"comparison": str(out_dir / f"{stem}.png"), "difference": str(out_dir / f"{stem}.diff.png")}
    write_comparison_png(pngs["comparison"], [shown, image, lambert, lambert * lambert_scale], exposure)
    write_difference_png(pngs["difference"], np.where(mask[..., None], image, 0.0),
                         np.where(mask[..., None], shown, 0.0), exposure)
    return {
        "technique": technique,
        "reference": "volpath",
        "light_dir": list(lobe.direction),
        "lobe_exponent": lobe.exponent,
        "lobe_directions": len(directions),
        "specular": "subtracted from the truth",
        "specular_share": float(truth.specular[mask].sum() / (reference + truth.specular)[mask].sum()),
        **pixels["rmse_relative"],
        "technique_scale": technique_scale.tolist(),
        "lambert_albedo": {name: albedo.tolist() for name, albedo in albedos.items()},
        "lambert_scale": lambert_scale.tolist(),
        "noise_floor": pixels["noise_floor"],
        # the truth's noise adds in quadrature to each error (it is independent of the image compared)
        "rmse_relative_denoised": pixels["rmse_relative_denoised"],
        "measures": measures,
        "rmse_object": rmse(image, shown, exposure, mask),
        "rmse_object_lambert": rmse(lambert, shown, exposure, mask),
        "exposure": exposure,
        "pixels": int(mask.sum()),
        "spp": spp,
        "image_size": [size, size],
        "mitsuba": mi.__version__,
        "truth_seconds": truth.seconds,
        "truth_cached": cached,
        "pngs": pngs,
    }


def _body(path: Path, mesh: int, surface, world: np.ndarray, material: Material, mm_per_unit: float) -> Body:
    """`surface` (file units) moved to the world by `world` (4, 4) as a closed, outward-wound
    `Body`; VerifyError for an open surface (the medium would have no inside)."""
    edges = np.sort(surface.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts != 2):
        raise VerifyError(f"verify: {path}: mesh {mesh} is not closed ({int(np.sum(counts != 2))} edges not shared "
                          "by two triangles); volpath needs a surface around the medium")
    linear = world[:3, :3]
    positions = surface.positions @ linear.T + world[:3, 3]
    normals = surface.normals @ np.linalg.inv(linear)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    faces = surface.faces.astype(np.int64)
    p0, p1, p2 = (positions[faces[:, i]] for i in range(3))
    if np.einsum("ij,ij->", p0, np.cross(p1, p2)) < 0:  # 6 × signed volume: wound inward
        faces = faces[:, ::-1]
    return Body(positions, normals, np.ascontiguousarray(faces), material, float(mm_per_unit))
