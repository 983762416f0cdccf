"""``sssbake verify``: render an export with the shipped GLSL and the offline reference under one
camera and light, and measure the difference (shared by every technique, through its registry
hooks: `technique.Technique`).

Per mesh instance the reference is `reference.reference_scattering` over the welded surface of
what one draw holds (the technique's ``draw_unit``: a primitive, or all primitives of the mesh,
which share its atlas and throughput matrix, or the surface its normals were filtered on), in the
mesh's frame with its ``scaleMm``, mapped back to the file's render vertices. A technique whose
data the dipole cannot describe brings its own reference (``reference_item``: lpv's grids of a
heterogeneous field, compared with the same field at twice the resolution, "lpv 2x").

Lambert images (the baseline, and spectral's subsurface normals, which the runtime shades with the
plain Lambert shader) are per-vertex clamped cosines times shadow visibility, drawn as q, each
scaled by its per-channel least-squares fit to the reference: a normal field sets where light
lands, not the material's albedo.
"""

from __future__ import annotations

import json
import os
import time
from functools import partial
from pathlib import Path

import numpy as np

from sssbake.exporters.gltf_tables import SssbakeGltf, load_sssbake_gltf
from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.pipeline.core.errors import VerifyError
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.core.visibility import direction_visibility, point_visibility
from sssbake.pipeline.mesh.clean import WELD_TOLERANCE, weld_surface
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.scene import Primitive, Scene
from sssbake.pipeline.render.image_metrics import (
    best_fit_scale,
    rmse,
    shared_exposure,
    write_comparison_png,
    write_difference_png,
)
from sssbake.pipeline.render.items import PLAIN_ALBEDO, merged_primitive
from sssbake.pipeline.render.renderer import DEFAULT_LIGHT, Renderer, RenderLight, fit_camera
from sssbake.pipeline.techniques.footprint import footprint
from sssbake.pipeline.techniques.registry import BY_NAME, NAMES
from sssbake.pipeline.techniques.technique import VerifyShot, VerifyUnit
from sssbake.pipeline.verify.checked_reference import check_figures, checked_reference

REFERENCES = ("exact", "clustered", "checked")


def verify_file(path: str | os.PathLike, technique: str = "prt", light_dir=DEFAULT_LIGHT, size: int = 512,
                out_dir: str | os.PathLike | None = None, frames: int = 20, light_pos=None,
                reference_sum: str = "exact", lpv_steps: int | None = None, stock_viewer: bool = False,
                references: dict | None = None, picture_size: int | None = None) -> dict:
    """Render `path` (.glb) with `technique`'s runtime and with the offline reference.

    Parameters
    ----------
    light_dir : (3,) float
        World direction towards a directional light of unit irradiance.
    light_pos : (3,) float, optional
        World position of a point light instead (world units; the meshes' world transforms must
        not scale). Its intensity gives unit irradiance at the centre of the objects' bounds.
    reference_sum : str
        ``"exact"`` (every pair) or ``"clustered"`` (far sources through float64 clusters, ~1e-3
        of q; for meshes of 100k+ vertices, where the exact sum takes hours; see
        `reference.reference_scattering`) or ``"checked"`` (the clustered sum, checked against the
        exact sum at a random sample of vertices: `checked_reference`, the figure ``reference_check``).
    lpv_steps : int, optional
        lpv: propagation steps per frame (default: the runtime's, `lpv_propagate.LPV_DEFAULTS`).
    stock_viewer : bool
        Also render what a stock glTF viewer shows (`stock_figures`).
    references : dict, optional
        The dipole references computed so far (the same for every technique: a batch's report
        verifies each technique of an asset against one), filled here; a draw unit of the same
        file under the same world matrix, light and `reference_sum` reads its own from it.
    size : int
        Image width and height in pixels of the figures.
    picture_size : int, optional
        Width and height of the PNGs' images (default `size`): a report's pictures larger than the
        images its figures are measured on, drawn again at the figures' exposure.
    out_dir : path, optional
        Where the PNGs go (default: next to the file).

    Returns
    -------
    dict
        ``technique``, ``light_dir`` (towards the light from the objects' centre), ``light_pos``
        (None for a directional light), ``reference`` (`reference_sum`, or the technique's
        ``self_reference_label`` where it compared with its own reference; see
        `reference_label`), ``rmse_image``, ``rmse_object``, ``rmse_object_lambert``,
        ``lambert_scale``, ``bytes_per_vertex`` (`footprint`'s ``total``), ``bake_seconds``, ``frame_ms_sss``,
        ``frame_ms_plain``, ``reference_seconds``, ``seconds`` (the whole verification),
        ``exposure``, ``image_size``, ``picture_size`` (the PNGs'), ``pngs``, with a ``"checked"``
        reference ``reference_check`` (`checked_reference.check_figures`: the sample, and how far the
        RMSE figures can move from the exact reference's, with its 95 % interval), and
        the technique's own figures (``verify_figures``): spectral ``spectral_scale`` (the fit
        applied to its image), ``rmse_object_naive`` and ``naive_scale`` (Patro's naive normals,
        computed here from the file's geometry and material with the precompute's defaults), its
        ``frame_ms_sss`` the plain shader's with the subsurface normals; screen where screen
        space misses light (`screen_verify.screen_misses`): ``low_share_pixels``,
        ``missed_share``, ``missed_share_unlit``, ``missed_share_low_share``,
        ``bytes_per_material``; lpv where light leaks (`lpv_verify.lpv_leaks`): ``excess_share``,
        ``excess_share_unlit``, ``thin_cells``, ``lpv_steps``, ``bytes_per_mesh``. With a
        self-convergence reference also ``reference_resolution`` and ``reference_steps`` (its
        finest grid and its steps); with `stock_viewer` `stock_figures`' keys and
        ``pngs["stock"]``.
    """
    if reference_sum not in REFERENCES:
        raise VerifyError(f"verify: reference must be one of {list(REFERENCES)}, got {reference_sum!r}")
    if technique not in NAMES:
        raise VerifyError(f"verify: technique must be one of {list(NAMES)}, got {technique!r}")
    t_start = time.perf_counter()
    hooks = BY_NAME[technique]
    path = Path(path)
    light_world = light_direction(light_dir)
    point = None if light_pos is None else np.asarray(light_pos, dtype=np.float64)
    if point is not None and (point.shape != (3,) or not np.all(np.isfinite(point))):
        raise VerifyError(f"verify: light position must be three finite numbers, got {light_pos}")
    data = hooks.read(path)
    file, scene, instances = draw_instances(path, technique, data)
    mm_world = {_scale_mm(file, mi) for mi, _, _ in instances}
    if point is not None:
        scales = [abs(np.linalg.det(world[:3, :3])) for _, _, world in instances]
        if len(mm_world) > 1 or not np.allclose(scales, 1.0, rtol=1e-6):
            raise VerifyError(f"verify: {path}: a point light needs one scaleMm and unscaled world transforms")
        points = np.concatenate([(w[:3, :3] @ scene.meshes[mi].primitives[pi].positions.T).T + w[:3, 3]
                                 for mi, unit, w in instances for pi in unit])
        centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
        if not np.linalg.norm(point - centre) > 0:
            raise VerifyError(f"verify: the point light sits at the objects' centre {centre.tolist()}; move it")
        light_world = (point - centre) / np.linalg.norm(point - centre)
        intensity = float(np.linalg.norm(point - centre) * next(iter(mm_world))) ** 2

    drawn, sss_items, timed_items, ref_items, lambert_items = [], [], [], [], []
    self_references, dipole_references, checks = [], 0, []  # (resolution, steps) of each self-reference
    runtime, memo = {"lpv_steps": lpv_steps}, {}  # the hooks' settings and what they keep across units
    references = {} if references is None else references
    t_ref = time.perf_counter()
    for mi, unit, world in instances:
        prim, material, mm, surface, weld = unit_surface(file, scene, mi, unit)
        linear = world[:3, :3]
        if point is None:
            omega = np.linalg.solve(linear, light_world)
            omega /= np.linalg.norm(omega)
            light = Light("directional", tuple(omega))
            visible = direction_visibility(surface.positions, surface.faces, surface.normals, omega[None])[weld, 0]
            towards, weight = omega[None], visible
        else:
            local = np.linalg.solve(linear, point - world[:3, 3])
            light = Light("point", position=tuple(local), intensity=intensity)
            visible = point_visibility(surface.positions, surface.faces, surface.normals, local)[weld]
            to_light = local - prim.positions
            distance = np.linalg.norm(to_light, axis=1)
            towards = to_light / np.maximum(distance, 1e-300)[:, None]
            weight = visible * intensity / np.maximum(distance * mm, 1e-300) ** 2
        base = dict(positions=prim.positions, normals=prim.normals, faces=prim.faces, model=world, eta=material.eta)
        at = VerifyUnit(mi, tuple(unit), prim, surface, weld, mm, material, file.extension(file.gltf.meshes[mi]), base,
                        partial(lambert_q, towards=towards, weight=weight))
        own = hooks.reference_item(path, at, data, runtime, memo)
        if own is not None:
            ref_items.append(own[0])
            self_references.append(own[1])
        else:
            key = (str(path), mi, tuple(unit), world.tobytes(), light, reference_sum)
            if key not in references:
                references[key] = (checked_reference(surface, mm, material, light) if reference_sum == "checked" else
                                   (reference_scattering(surface, mm, material, light,
                                                         clustered=reference_sum == "clustered"), None))
            ref, check = references[key]
            checks += [check] if check is not None else []
            ref_items.append({**base, "q": ref[:, weld].T})
            dipole_references += 1
        compared, timed = hooks.verify_items(at, data, runtime)
        drawn.append(at)
        sss_items.append(compared)
        timed_items.append(timed)
        lambert_items.append({**base, "q": at.lambert_q(prim.normals)})
    reference_seconds = time.perf_counter() - t_ref
    if not self_references and not any(np.any(it["q"] > 0) for it in ref_items):
        raise VerifyError(f"verify: {path}: the light reaches no vertex (inside the object, or behind it)")

    world_points = np.concatenate([(it["model"][:3, :3] @ it["positions"].T).T + it["model"][:3, 3] for it in sss_items])
    camera = fit_camera(world_points)
    if point is None:
        light = RenderLight(False, tuple(light_world), 1.0)
    else:
        light = RenderLight(True, tuple(point), intensity, next(iter(mm_world)))

    def draw(side: int, exposure: float | None) -> tuple[VerifyShot, np.ndarray, list, dict, np.ndarray, np.ndarray,
                                                          float]:
        """Everything compared at `side`²: the shot (its exposure `exposure`, or the reference's
        `shared_exposure` for None), the technique's image, pictures and figures
        (`Technique.verify_figures`) and best-fit Lambert's image, scale and RMSE."""
        renderer = Renderer((side, side))
        image, mask = renderer.render(sss_items, camera, light)
        reference, ref_mask = renderer.render(ref_items, camera, light)
        if self_references and not np.any(reference[ref_mask] > 0):
            raise VerifyError(f"verify: {path}: the light reaches no cell (inside the object, or behind it)")
        exposure = shared_exposure(reference, ref_mask) if exposure is None else exposure

        def fitted(drawn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """(H, W, 3) `drawn` times its per-channel best fit (3,) to the reference, and the fit."""
            fit = best_fit_scale(drawn, reference, ref_mask)
            return drawn * fit, fit

        lambert, scale, lambert_error = best_fit_lambert(renderer, lambert_items, camera, light, reference, ref_mask,
                                                         exposure)
        shot = VerifyShot(renderer, camera, light, image, reference, ref_mask, ref_mask | mask, exposure, lambert > 0,
                          fitted)
        return shot, *hooks.verify_figures(drawn, sss_items, shot), lambert, scale, lambert_error

    measured = draw(size, None)
    shot, image, pictures, extra, lambert, scale, lambert_error = measured
    reference, exposure = shot.reference, shot.exposure
    plain_items = [{k: v for k, v in it.items() if k != "q"} | {"albedo": PLAIN_ALBEDO} for it in lambert_items]
    frame_ms = {  # timed before a renderer for the pictures exists: one GL context in use
        # the technique's runtime as it ships (spectral's: the plain shader fed the subsurface normals)
        "frame_ms_sss": shot.renderer.frame_ms(timed_items, camera, light, frames),
        # plain: the standard Lambert + specular shader, no SSS data
        "frame_ms_plain": shot.renderer.frame_ms(plain_items, camera, light, frames)}
    # the figures stay at `size`² (the budget's and the pilot's); larger pictures are drawn again, as bright
    big, big_image, big_pictures, _, big_lambert, _, _ = (measured if picture_size in (None, size)
                                                          else draw(picture_size, exposure))

    out_dir = Path(out_dir) if out_dir is not None else path.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{path.stem}.verify.{technique}"
    pngs = {"comparison": str(out_dir / f"{stem}.png"), "difference": str(out_dir / f"{stem}.diff.png")}
    write_comparison_png(pngs["comparison"], [big.reference, big_image, big_lambert, *big_pictures], exposure)
    write_difference_png(pngs["difference"], big_image, big.reference, exposure)
    if stock_viewer:
        pngs["stock"] = str(out_dir / f"{stem}.stock.png")
        extra.update(stock_figures(path, [it["positions"] for it in sss_items], camera, light, size, reference,
                                   shot.reference_mask, exposure, pngs["stock"]))

    report = _bake_report(path)
    return {
        "technique": technique,
        "light_dir": light_world.tolist(),
        "light_pos": None if point is None else point.tolist(),
        "reference": reference_label(reference_sum, dipole_references, len(self_references),
                                     hooks.self_reference_label),
        "rmse_image": rmse(image, reference, exposure),
        "rmse_object": rmse(image, reference, exposure, shot.mask),
        "rmse_object_lambert": lambert_error,
        "lambert_scale": scale.tolist(),
        # attributes and tables per render vertex as the file holds them (`footprint`; 0: data in JSON alone)
        "bytes_per_vertex": footprint(inspect_glb(path))["techniques"].get(technique, {"total": 0.0})["total"],
        "bake_seconds": report.get("seconds"),
        **frame_ms,
        "reference_seconds": reference_seconds,
        **({"reference_check": check_figures(checks, exposure)} if checks else {}),
        "seconds": time.perf_counter() - t_start,
        "exposure": exposure,
        "image_size": [size, size],
        "picture_size": [picture_size or size] * 2,
        "pngs": pngs,
        **extra,
        **({"reference_resolution": max(r for r, _ in self_references),
            "reference_steps": max(st for _, st in self_references)} if self_references else {}),
    }


def held_techniques(path: str | os.PathLike) -> list[str]:
    """The registered techniques whose data `path` (.glb) holds (`footprint`), in the registry's order:
    what ``sssbake verify`` checks without ``--technique``.

    Raises
    ------
    AssetError
        The file holds no sssbake data (`inspect_glb`'s `required`), or one of its tables or ``_``
        attributes is stale.
    VerifyError
        It holds the standard fallback alone.
    """
    held = [t for t in footprint(inspect_glb(path, required=True))["techniques"] if t in NAMES]
    if not held:
        raise VerifyError(f"{path}: holds no technique verify checks, only the standard fallback (bake with "
                          f"--techniques and one of {', '.join(NAMES)})")
    return held


def light_direction(light_dir) -> np.ndarray:
    """(3,) float64 unit vector of `light_dir` (three finite numbers, not all zero; VerifyError otherwise)."""
    light = np.asarray(light_dir, dtype=np.float64)
    if light.shape != (3,) or not np.all(np.isfinite(light)) or not np.linalg.norm(light) > 0:
        raise VerifyError(f"verify: light direction must be three finite numbers, not all zero, got {light_dir}")
    return light / np.linalg.norm(light)


def draw_instances(path: Path, technique: str, data: dict) -> tuple[SssbakeGltf, Scene, list]:
    """What verify draws of `path`: its sssbake data, its scene and one ``(mesh, primitives,
    world)`` per draw unit (`Technique.draw_unit`) of every mesh instance holding `technique`'s
    `data` (``world`` (4, 4) float64 object to world); VerifyError when there is none."""
    file = load_sssbake_gltf(path, required=True)
    scene = load_scene(str(path))
    instances = []
    for mi, worlds in sorted(scene.mesh_instances().items()):
        held = [pi for pi in range(len(scene.meshes[mi].primitives)) if (mi, pi) in data]
        units = [[pi] for pi in held] if BY_NAME[technique].draw_unit == "primitive" else ([held] if held else [])
        instances += [(mi, unit, world) for unit in units for world in worlds]
    if not instances:
        raise VerifyError(f"verify: {path} has no drawable primitive with {technique} data")
    return file, scene, instances


def unit_surface(file: SssbakeGltf, scene: Scene, mesh: int, primitives: list[int]
                 ) -> tuple[Primitive, Material, float, Surface, np.ndarray]:
    """One draw unit's primitives of `mesh` merged (n render vertices), their material, the mesh's
    millimetres per unit, their welded surface and the (n,) welded vertex of each render vertex."""
    prims = [scene.meshes[mesh].primitives[pi] for pi in primitives]
    prim = merged_primitive(prims)
    # Seam vertices share positions: weld them, or a zero distance would read Rd(0).
    diagonal = float(np.linalg.norm(np.ptp(prim.positions, axis=0)))
    surface = weld_surface([prim], WELD_TOLERANCE * diagonal)
    return prim, _material(file, prims[0].material), _scale_mm(file, mesh), surface, surface.weld[0]


def reference_label(reference_sum: str, dipoles: int, self_references: int, self_label: str | None) -> str:
    """The ``reference`` of `verify_file`: `reference_sum` when every instance is compared with the
    dipole, the technique's `self_label` when every one with its own reference, both (``"; "``)
    when mixed."""
    if not self_references:
        return reference_sum
    return self_label if not dipoles else f"{reference_sum} (homogeneous meshes); {self_label}"


def stock_figures(path: Path, positions: list[np.ndarray], camera, light, size: int, reference: np.ndarray,
                  mask: np.ndarray, exposure: float, png: str) -> dict:
    """What a stock glTF viewer shows (pyrender: `stock_viewer.render_stock_viewer`) of `path`'s
    fallback material and of the spectral normals variant ``<stem>.sss_normals.glb`` when the bake
    wrote one, against verify's reference, unscaled: a viewer shows the base colour as it is.

    Parameters
    ----------
    positions : list of (n, 3) float
        The vertex positions of the primitives verify compares (the stock pictures draw those alone).
    camera, light : Camera, RenderLight
        verify's.
    reference : (H, W, 3) float32
    mask : (H, W) bool
        The reference's coverage.
    exposure : float
        verify's shared exposure.
    png : str
        Where reference | stock | stock variant (without one: reference | stock) go.

    Returns
    -------
    dict
        ``rmse_object_stock`` (over the reference's or the stock image's pixels), ``stock_scale``
        (3,) (the per-channel best fit of the stock image to the reference, not applied: how far
        the viewer's brightness is off), ``stock_variant`` (the variant's path, None without one),
        ``rmse_object_stock_variant`` (None without one), ``stock_seconds`` (the renders, with
        pyrender's import on a process's first call).
    """
    from sssbake.pipeline.render.stock_viewer import render_stock_viewer

    t = time.perf_counter()
    stock, covered = render_stock_viewer(path, camera, light, size, exposure, positions)
    variant = path.with_suffix(".sss_normals.glb")
    shown, figures = [reference, stock], {"stock_variant": None, "rmse_object_stock_variant": None}
    if variant.is_file():
        normals, normals_covered = render_stock_viewer(variant, camera, light, size, exposure, positions)
        shown.append(normals)
        figures = {"stock_variant": str(variant),
                   "rmse_object_stock_variant": rmse(normals, reference, exposure, mask | normals_covered)}
    seconds = time.perf_counter() - t
    write_comparison_png(png, shown, exposure)
    return {"rmse_object_stock": rmse(stock, reference, exposure, mask | covered),
            "stock_scale": best_fit_scale(stock, reference, mask).tolist(), **figures, "stock_seconds": seconds}


def best_fit_lambert(renderer: Renderer, items: list[dict], camera, light, reference: np.ndarray, mask: np.ndarray,
                     exposure: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The baseline a technique must beat, shared by verify and the planner's pilot: Lambert
    `items` (``q`` from `lambert_q`) drawn under `camera` and `light`, times the per-channel scale
    that best fits `reference` over its coverage `mask` (a normal field sets where light lands,
    not the material's albedo).

    Parameters
    ----------
    reference : (H, W, 3) float
    mask : (H, W) bool
    exposure : float
        The comparison's shared exposure.

    Returns
    -------
    image : (H, W, 3) float
        The fitted Lambert.
    scale : (3,) float64
        The fit (``lambert_scale``).
    rmse_object : float
        Its RMSE against `reference` over `mask` (``rmse_object_lambert``).
    """
    drawn = renderer.render(items, camera, light)[0]
    scale = best_fit_scale(drawn, reference, mask)
    image = drawn * scale
    return image, scale, rmse(image, reference, exposure, mask)


def lambert_q(field: np.ndarray, towards: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(n, 3) grey q of unit normals `field` (n, 3) at the render vertices: clip(n · towards, 0) ·
    weight, `towards` (1, 3) or (n, 3) unit vectors to the light, `weight` (n,) its visible
    irradiance."""
    return np.repeat((np.clip(np.sum(field * towards, axis=1), 0.0, None) * weight)[:, None], 3, axis=1)


def _scale_mm(file: SssbakeGltf, mesh: int) -> float:
    """Mesh `mesh`'s millimetres per file unit, from its extension object."""
    scale = (file.extension(file.gltf.meshes[mesh]) or {}).get("scaleMm")
    if not isinstance(scale, (int, float)) or not scale > 0:
        raise VerifyError(f"verify: {file.path}: mesh {mesh} has no positive SSSBAKE_subsurface.scaleMm")
    return float(scale)


def _material(file: SssbakeGltf, index: int | None) -> Material:
    data = None
    if index is not None:
        data = (file.extension(file.gltf.materials[index]) or {}).get("material")
    if not data:
        raise VerifyError(f"verify: {file.path}: a scattering primitive's material has no SSSBAKE_subsurface.material")
    return Material.from_json(data)


def _bake_report(path: Path) -> dict:
    report = path.with_suffix(".report.json")
    try:
        return json.loads(report.read_text())
    except (OSError, ValueError):
        return {}
