"""``sssbake verify``: render an export with the shipped GLSL and the offline reference under one
camera and light, and measure the difference (shared by every technique).

Per mesh instance the reference is `reference.reference_scattering` over the welded surface of
what one draw holds (prt: a primitive; kernels and spectral: all primitives of the mesh, which
share its atlas and throughput matrix, or the surface its normals were filtered on), in the mesh's
frame with its ``scaleMm``, mapped back to the file's render vertices. The dipole knows only a
homogeneous medium: an lpv grid voxelised from a heterogeneous field (``field`` "marble") is
compared with its own self-convergence reference instead (`lpv_reference`): the same field, as the
file records it, re-voxelised from the welded surface at twice the resolution, calibrated the same
way and drawn by the same lpv runtime with proportionally more steps ("lpv 2x").

Lambert images (the baseline, and spectral's subsurface normals, which the runtime shades with the
plain Lambert shader) are per-vertex clamped cosines times shadow visibility, drawn as q, each
scaled by its per-channel least-squares fit to the reference: a normal field sets where light
lands, not the material's albedo.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pygltflib

from ..exporters.read_kernels import read_kernels_glb
from ..exporters.read_lpv import read_lpv_glb, read_lpv_sources_glb
from ..exporters.read_prt import read_prt_glb
from ..exporters.read_screen import read_screen_glb
from ..exporters.read_spectral import read_spectral_glb
from .clean import WELD_TOLERANCE, Surface, area_weighted_normals, weld_surface
from .load import load_scene
from .scene import Primitive
from .materials import Material
from .naive_normals import naive_normals
from .reference import Light, reference_scattering
from .lpv_calibrate import render_scales
from .lpv_data import LpvGrid
from .lpv_grid import voxelise
from .lpv_layout import LpvSource, lpv_bytes, lpv_tables
from .lpv_matrices import propagation_matrices
from .lpv_propagate import LPV_DEFAULTS, MAX_STEPS
from .spectral_precompute import SPECTRAL_DEFAULTS, naive_parameters
from .visibility import direction_visibility, point_visibility

TECHNIQUES = ("prt", "kernels", "spectral", "screen", "lpv")
READERS = {"prt": read_prt_glb, "kernels": read_kernels_glb, "spectral": read_spectral_glb,
           "screen": read_screen_glb, "lpv": read_lpv_glb}
#: A technique's bytes per vertex from its block of the bake report (spectral: the normal per
#: render vertex plus the optional re-filtering tables per vertex; screen: nothing per vertex, its
#: tables are per material; lpv: nothing per vertex, its grid is per mesh).
BYTES_PER_VERTEX = {"prt": lambda r: r["bytesPerVertex"]["total"], "kernels": lambda r: r["bytes"]["perVertex"],
                    "spectral": lambda r: r["bytes"]["perVertex"] + r["bytes"]["normalPerRenderVertex"],
                    "screen": lambda r: 0.0, "lpv": lambda r: 0.0}
#: A screen pixel whose gather found less than this share of Rd's integral on the surface counts
#: as missing surface (silhouettes, occluders, the image's edge).
LOW_SHARE = 0.9
REFERENCES = ("exact", "clustered")
DEFAULT_LIGHT = (0.4, 0.8, 0.45)
#: Colour of the plain shader that frame times are compared with (its cost does not depend on it).
PLAIN_ALBEDO = (0.8, 0.8, 0.8)
#: The ``reference`` of an lpv verify whose grids came from a heterogeneous field (`lpv_reference`).
LPV_SELF_REFERENCE = "lpv 2x (heterogeneous medium: no closed-form reference)"
#: Finest grid `lpv_reference` builds, cells along the longest side: 2x a 128³ bake, 16.8 M cells
#: (8x its cells and 16x its propagation work); finer bakes cannot be checked against 2x.
LPV_REFERENCE_MAX_RESOLUTION = 256


def verify_file(path: str | os.PathLike, technique: str = "prt", light_dir=DEFAULT_LIGHT, size: int = 512,
                out_dir: str | os.PathLike | None = None, frames: int = 20, light_pos=None,
                reference_sum: str = "exact", lpv_steps: int = LPV_DEFAULTS.steps, stock_viewer: bool = False) -> dict:
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
        `reference.reference_scattering`).
    lpv_steps : int
        lpv: propagation steps per frame.
    stock_viewer : bool
        Also render what a stock glTF viewer shows (`stock_figures`).
    size : int
        Image width and height in pixels.
    out_dir : path, optional
        Where the PNGs go (default: next to the file).

    Returns
    -------
    dict
        ``technique``, ``light_dir`` (towards the light from the objects' centre), ``light_pos``
        (None for a directional light), ``reference`` (`reference_sum`, or `LPV_SELF_REFERENCE`
        where lpv grids of a heterogeneous field were compared with `lpv_reference`; see
        `reference_label`), ``rmse_image``, ``rmse_object``, ``rmse_object_lambert``,
        ``lambert_scale``, ``bytes_per_vertex``, ``bake_seconds``, ``frame_ms_sss``,
        ``frame_ms_plain``, ``reference_seconds``, ``exposure``, ``image_size``, ``pngs``; spectral
        also ``spectral_scale`` (the fit applied to its image), ``rmse_object_naive`` and
        ``naive_scale`` (Patro's naive normals, computed here from the file's geometry and
        material with the precompute's defaults). Spectral's ``frame_ms_sss`` is the plain
        shader's with the subsurface normals. Screen also reports where screen space misses light
        (`screen_misses`): ``low_share_pixels``, ``missed_share``, ``missed_share_unlit``,
        ``missed_share_low_share``, ``bytes_per_material``; lpv reports where light leaks
        (`lpv_leaks`): ``excess_share``, ``excess_share_unlit``, ``thin_cells``, ``lpv_steps``,
        ``bytes_per_mesh``, and with a self-convergence reference ``reference_resolution`` and
        ``reference_steps`` (its finest grid and its steps). With `stock_viewer` also
        `stock_figures`' keys and ``pngs["stock"]``.
    """
    from .image_metrics import (best_fit_scale, rmse, shared_exposure, write_comparison_png,
                                write_difference_png)
    from .render import Renderer, RenderLight, fit_camera

    if reference_sum not in REFERENCES:
        raise ValueError(f"verify: reference must be one of {list(REFERENCES)}, got {reference_sum!r}")
    if technique not in TECHNIQUES:
        raise ValueError(f"verify: technique must be one of {list(TECHNIQUES)}, got {technique!r}")
    path = Path(path)
    light_world = np.asarray(light_dir, dtype=np.float64)
    if light_world.shape != (3,) or not np.all(np.isfinite(light_world)) or not np.linalg.norm(light_world) > 0:
        raise ValueError(f"verify: light direction must be three finite numbers, not all zero, got {light_dir}")
    light_world = light_world / np.linalg.norm(light_world)
    point = None if light_pos is None else np.asarray(light_pos, dtype=np.float64)
    if point is not None and (point.shape != (3,) or not np.all(np.isfinite(point))):
        raise ValueError(f"verify: light position must be three finite numbers, got {light_pos}")
    data = READERS[technique](path)
    sources = read_lpv_sources_glb(path) if technique == "lpv" else {}
    gltf = pygltflib.GLTF2.load(str(path))
    scene = load_scene(str(path))
    instances = []
    for mi, worlds in sorted(scene.mesh_instances().items()):
        held = [pi for pi in range(len(scene.meshes[mi].primitives)) if (mi, pi) in data]
        # prt and screen draw a primitive each (screen: its material's tables); the others a mesh
        units = [[pi] for pi in held] if technique in ("prt", "screen") else ([held] if held else [])
        instances += [(mi, unit, world) for unit in units for world in worlds]
    if not instances:
        raise ValueError(f"verify: {path} has no drawable primitive with {technique} data")
    mm_world = {float((gltf.meshes[mi].extras or {}).get("sssbake", {})["scaleMm"]) for mi, _, _ in instances}
    if point is not None:
        scales = [abs(np.linalg.det(world[:3, :3])) for _, _, world in instances]
        if len(mm_world) > 1 or not np.allclose(scales, 1.0, rtol=1e-6):
            raise ValueError(f"verify: {path}: a point light needs one scaleMm and unscaled world transforms")
        points = np.concatenate([(w[:3, :3] @ scene.meshes[mi].primitives[pi].positions.T).T + w[:3, 3]
                                 for mi, unit, w in instances for pi in unit])
        centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
        if not np.linalg.norm(point - centre) > 0:
            raise ValueError(f"verify: the point light sits at the objects' centre {centre.tolist()}; move it")
        light_world = (point - centre) / np.linalg.norm(point - centre)
        intensity = float(np.linalg.norm(point - centre) * next(iter(mm_world))) ** 2

    sss_items, ref_items, lambert_items, naive_items, normal_items = [], [], [], [], []
    self_references, dipole_references = [], 0  # (resolution, steps) of each lpv 2x reference
    finer_grids = {}  # mesh index -> `lpv_reference`
    t_ref = time.perf_counter()
    for mi, unit, world in instances:
        prims = [scene.meshes[mi].primitives[pi] for pi in unit]
        prim = merged_primitive(prims)
        material = _material(gltf, prims[0].material, path)
        mm = float(gltf.meshes[mi].extras["sssbake"]["scaleMm"])
        normals = prim.normals
        # Seam vertices share positions: weld them, or a zero distance would read Rd(0).
        diagonal = float(np.linalg.norm(np.ptp(prim.positions, axis=0)))
        surface = weld_surface([prim], WELD_TOLERANCE * diagonal)
        weld = surface.weld[0]
        linear = world[:3, :3]
        # Lambert of a normal field n: clip(n · towards, 0) · weight per render vertex.
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

        def lambert_q(field: np.ndarray) -> np.ndarray:
            """(n, 3) grey q of unit normals `field` (n, 3) at the render vertices."""
            return np.repeat((np.clip(np.sum(field * towards, axis=1), 0.0, None) * weight)[:, None], 3, axis=1)

        base = dict(positions=prim.positions, normals=normals, faces=prim.faces, model=world, eta=material.eta)
        source = sources.get((mi, unit[0])) if technique == "lpv" else None
        lpv_field = str(source.field) if source is not None else None
        if technique == "lpv" and source is None and _lpv_field(gltf, mi) != "homogeneous":
            raise ValueError(f"verify: {path}: mesh {mi}'s lpv grid comes from a {_lpv_field(gltf, mi)!r} field but the "
                             "file does not record its parameters (schema before 1.8.0): bake it again")
        if lpv_field is not None and lpv_field != "homogeneous":
            if mi not in finer_grids:  # one per mesh, whatever the instances' transforms
                finer_grids[mi] = lpv_reference(surface, source, data[(mi, unit[0])][0], lpv_steps)
            finer, finer_scales, finer_steps, finer_resolution = finer_grids[mi]
            ref_items.append({**base, "lpv": finer, "lpv_matrices": propagation_matrices(),
                              "lpv_scales": finer_scales, "lpv_steps": finer_steps})
            self_references.append((finer_resolution, finer_steps))
        else:
            ref = reference_scattering(surface, mm, material, light, clustered=reference_sum == "clustered")[:, weld]
            ref_items.append({**base, "q": ref.T})
            dipole_references += 1
        if technique == "prt":
            sss_items.append({**base, "prt": data[(mi, unit[0])]})
        elif technique == "screen":
            sss_items.append({**base, "screen": data[(mi, unit[0])], "mm_per_unit": mm})
        elif technique == "lpv":
            grid, matrices, scales = data[(mi, unit[0])]
            sss_items.append({**base, "lpv": grid, "lpv_matrices": matrices, "lpv_scales": scales,
                              "lpv_steps": lpv_steps})
        elif technique == "kernels":
            kernels = data[(mi, unit[0])][0]
            sss_items.append({**base, "kernels": kernels, "uvs": prim.uvs[-1],
                              "vertex_ids": np.concatenate([data[(mi, pi)][1] for pi in unit])})
        else:
            subsurface = np.concatenate([data[(mi, pi)] for pi in unit])
            # The file's normals stay the item's: the q draw's exit Fresnel then matches the baseline's.
            sss_items.append({**base, "q": lambert_q(subsurface)})
            naive_items.append({**base, "q": lambert_q(default_naive_normals(surface, mm, material)[weld])})
            normal_items.append({**base, "normals": subsurface, "albedo": PLAIN_ALBEDO})
        lambert_items.append({**base, "q": lambert_q(normals)})
    reference_seconds = time.perf_counter() - t_ref
    if not self_references and not any(np.any(it["q"] > 0) for it in ref_items):
        raise ValueError(f"verify: {path}: the light reaches no vertex (inside the object, or behind it)")

    renderer = Renderer((size, size))
    world_points = np.concatenate([(it["model"][:3, :3] @ it["positions"].T).T + it["model"][:3, 3] for it in sss_items])
    camera = fit_camera(world_points)
    if point is None:
        light = RenderLight(False, tuple(light_world), 1.0)
    else:
        light = RenderLight(True, tuple(point), intensity, next(iter(mm_world)))
    image, mask = renderer.render(sss_items, camera, light)
    reference, ref_mask = renderer.render(ref_items, camera, light)
    if self_references and not np.any(reference[ref_mask] > 0):
        raise ValueError(f"verify: {path}: the light reaches no cell (inside the object, or behind it)")
    exposure = shared_exposure(reference, ref_mask)

    def fitted(drawn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, 3) `drawn` times its per-channel best fit (3,) to the reference, and the fit."""
        fit = best_fit_scale(drawn, reference, ref_mask)
        return drawn * fit, fit

    lambert, scale = fitted(renderer.render(lambert_items, camera, light)[0])
    shown, extra = [reference, image, lambert], {}
    if technique == "spectral":
        image, spectral_scale = fitted(image)
        naive, naive_scale = fitted(renderer.render(naive_items, camera, light)[0])
        shown = [reference, image, lambert, naive]
        extra = {"spectral_scale": spectral_scale.tolist(), "naive_scale": naive_scale.tolist(),
                 "rmse_object_naive": rmse(naive, reference, exposure, ref_mask)}
    elif technique == "screen":
        extra = screen_misses(renderer, sss_items, camera, light, image, reference, ref_mask | mask, shown[2] > 0)
    elif technique == "lpv":
        extra = lpv_leaks(sss_items, image, reference, ref_mask | mask, shown[2] > 0)

    out_dir = Path(out_dir) if out_dir is not None else path.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"{path.stem}.verify.{technique}"
    pngs = {"comparison": str(out_dir / f"{stem}.png"), "difference": str(out_dir / f"{stem}.diff.png")}
    write_comparison_png(pngs["comparison"], shown, exposure)
    write_difference_png(pngs["difference"], image, reference, exposure)
    if stock_viewer:
        pngs["stock"] = str(out_dir / f"{stem}.stock.png")
        extra.update(stock_figures(path, [it["positions"] for it in sss_items], camera, light, size, reference,
                                   ref_mask, exposure, pngs["stock"]))

    report = _bake_report(path)
    technique_reports = list(report.get(technique, {}).values())
    plain_items = [{k: v for k, v in it.items() if k != "q"} | {"albedo": PLAIN_ALBEDO} for it in lambert_items]
    return {
        "technique": technique,
        "light_dir": light_world.tolist(),
        "light_pos": None if point is None else point.tolist(),
        "reference": reference_label(reference_sum, dipole_references, len(self_references)),
        "rmse_image": rmse(image, reference, exposure),
        "rmse_object": rmse(image, reference, exposure, ref_mask | mask),
        "rmse_object_lambert": rmse(lambert, reference, exposure, ref_mask),
        "lambert_scale": scale.tolist(),
        "bytes_per_vertex": BYTES_PER_VERTEX[technique](technique_reports[0]) if technique_reports else None,
        "bake_seconds": report.get("seconds"),
        # spectral's runtime is the plain shader fed the subsurface normals
        "frame_ms_sss": renderer.frame_ms(normal_items if technique == "spectral" else sss_items, camera, light,
                                          frames),
        # plain: the standard Lambert + specular shader, no SSS data
        "frame_ms_plain": renderer.frame_ms(plain_items, camera, light, frames),
        "reference_seconds": reference_seconds,
        "exposure": exposure,
        "image_size": [size, size],
        "pngs": pngs,
        **extra,
        **({"reference_resolution": max(r for r, _ in self_references),
            "reference_steps": max(st for _, st in self_references)} if self_references else {}),
    }


def reference_label(reference_sum: str, dipoles: int, self_references: int) -> str:
    """The ``reference`` of `verify_file`: `reference_sum` when every instance is compared with the
    dipole, `LPV_SELF_REFERENCE` when every one with its lpv 2x, both (``"; "``) when mixed."""
    if not self_references:
        return reference_sum
    return LPV_SELF_REFERENCE if not dipoles else f"{reference_sum} (homogeneous meshes); {LPV_SELF_REFERENCE}"


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
    from .image_metrics import best_fit_scale, rmse, write_comparison_png
    from .stock_viewer import render_stock_viewer

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


def lpv_reference(surface: Surface, source: LpvSource, grid: LpvGrid, steps: int
                  ) -> tuple[LpvGrid, np.ndarray, int, int]:
    """The self-convergence reference of an lpv grid voxelised from a heterogeneous field.

    The dipole has no answer for a veined medium, so the reference is the same technique one
    refinement further on: the field the file records (`lpv_layout.LpvSource`) re-voxelised from
    `surface` (the welded surface verify draws, in the mesh's frame) with the same padding and
    supersampling at twice the file's resolution (at most `LPV_REFERENCE_MAX_RESOLUTION`), its
    rendering's scale calibrated the same way (`lpv_calibrate.render_scales`), and as many more
    propagation steps as the cells are smaller (light moves one cell per step, so the reference's
    light travels as far in mm per frame as the file's). The image difference then measures how far
    the file's grid and step count are from converged, as `lpv_tradeoff` measures a veined medium
    against its finest configuration, not the distance to the truth.

    Parameters
    ----------
    surface : Surface
        Closed, file units.
    source : LpvSource
        What the file's grid was voxelised from.
    grid : LpvGrid
        The file's grid (its cell and index of refraction).
    steps : int
        The runtime's propagation steps for the file's grid.

    Returns
    -------
    finer : LpvGrid
    scales : (S, 3) float64
        The finer grid's rendering scale for 1 .. S steps.
    finer_steps : int
        S: the reference's propagation steps.
    resolution : int
        The finer grid's cells along the longest side.
    """
    resolution = int(source.grid.resolution)
    finer = min(2 * resolution, LPV_REFERENCE_MAX_RESOLUTION)
    if finer <= resolution:
        raise ValueError(f"verify: an lpv grid of {resolution} cells has no finer self-convergence reference within "
                         f"{LPV_REFERENCE_MAX_RESOLUTION} cells")
    options = replace(source.grid, resolution=finer)
    voxels = voxelise(surface, source.mm_per_unit, source.material_field(), grid.eta, options)
    finer_steps = min(max(1, int(round(steps * grid.cell_mm / voxels.cell_mm))), MAX_STEPS)
    return voxels, render_scales(voxels, finer_steps), finer_steps, finer


def screen_misses(renderer, items: list[dict], camera, light, image: np.ndarray, reference: np.ndarray,
                  mask: np.ndarray, lit: np.ndarray) -> dict:
    """Where the screen technique's image lacks the reference's light, and why.

    Parameters
    ----------
    items : list of dict
        The screen render items.
    image, reference : (H, W, 3) float32
    mask : (H, W) bool
        The object's pixels.
    lit : (H, W, 3) or (H, W) bool
        Pixels the light reaches directly (the Lambert image's non-zero pixels).

    Returns
    -------
    dict
        ``low_share_pixels``: share of the object's pixels whose gather found under `LOW_SHARE`
        of Rd's integral on the surface (the smallest over the items covering it);
        ``missed_share``: Σ max(reference - image, 0) / Σ reference over the object's pixels
        (all channels); ``missed_share_unlit``, ``missed_share_low_share``: the parts of it at
        pixels the light does not reach directly (light that came through the object from
        surfaces the camera cannot see) and at low-share pixels; ``bytes_per_material``: the
        tables' float32 bytes of the first item.
    """
    share = np.ones(image.shape[:2])
    for item in items:
        passes = renderer.screen_passes(item, camera, light)
        share = np.where(passes["covered"], np.minimum(share, passes["share"]), share)
    lit = lit.any(axis=-1) if lit.ndim == 3 else lit
    low = mask & (share < LOW_SHARE)
    missing = np.maximum(reference - image, 0.0).sum(axis=-1)
    total = max(float(reference[mask].sum()), 1e-300)
    samples = items[0]["screen"]
    return {"low_share_pixels": float(low.sum() / max(mask.sum(), 1)),
            "missed_share": float(missing[mask].sum() / total),
            "missed_share_unlit": float(missing[mask & ~lit].sum() / total),
            "missed_share_low_share": float(missing[low].sum() / total),
            "bytes_per_material": int(4 * (samples.offsets.size + samples.weights.size + samples.table.size))}


def lpv_leaks(items: list[dict], image: np.ndarray, reference: np.ndarray, mask: np.ndarray,
              lit: np.ndarray) -> dict:
    """Where the lpv technique's image has light the reference does not, and how coarse its grids
    are; `items` are the lpv render items, the other parameters as `screen_misses`'.

    Returns
    -------
    dict
        ``excess_share``: Σ max(image - reference, 0) / Σ reference over the object's pixels;
        ``excess_share_unlit``: its part at pixels the light does not reach directly (light that
        crossed the grid, through the object or across a gap the grid's cells bridge);
        ``thin_cells``: the share of the first grid's cells with medium that are mostly outside the
        surface (occupancy < 0.5: where cells bridge thin gaps); ``lpv_steps``; ``bytes_per_mesh``
        (the first grid's float32 tables).
    """
    lit = lit.any(axis=-1) if lit.ndim == 3 else lit
    excess = np.maximum(image - reference, 0.0).sum(axis=-1)
    total = max(float(reference[mask].sum()), 1e-300)
    grid = items[0]["lpv"]
    medium = grid.occupancy > 0
    return {"excess_share": float(excess[mask].sum() / total),
            "excess_share_unlit": float(excess[mask & ~lit].sum() / total),
            "thin_cells": float(np.mean(grid.occupancy[medium] < 0.5)) if medium.any() else 0.0,
            "lpv_steps": int(items[0]["lpv_steps"]),
            "bytes_per_mesh": lpv_bytes(lpv_tables(grid, items[0]["lpv_matrices"], items[0]["lpv_scales"],
                                                   "homogeneous"))["total"]}


def default_naive_normals(surface: Surface, mm_per_unit: float, material: Material) -> np.ndarray:
    """(n, 3) Patro's naive normals of `surface`'s vertices with the spectral precompute's defaults
    (σ_tr and radius from the material, `SPECTRAL_DEFAULTS.alpha`), without its eigensolve."""
    sigma_tr, radius = naive_parameters(material)
    return naive_normals(surface.positions * mm_per_unit, surface.normals, sigma_tr, SPECTRAL_DEFAULTS.alpha, radius)


def merged_primitive(prims: list) -> Primitive:
    """One primitive of all of `prims` (faces re-indexed), with normals where they lacked them."""
    normals = [p.normals if p.normals is not None else area_weighted_normals(p.positions, p.faces) for p in prims]
    offsets = np.cumsum([0] + [len(p.positions) for p in prims])
    uv_sets = min(len(p.uvs) for p in prims)
    return replace(prims[0], positions=np.concatenate([p.positions for p in prims]),
                   normals=np.concatenate(normals),
                   faces=np.concatenate([p.faces + o for p, o in zip(prims, offsets)]),
                   uvs=tuple(np.concatenate([p.uvs[len(p.uvs) - uv_sets + t] for p in prims]) for t in range(uv_sets)),
                   tangents=None, colors=None)


def _lpv_field(gltf: pygltflib.GLTF2, mesh: int) -> str:
    """The ``field`` a mesh's lpv block names (``"homogeneous"`` when it names none)."""
    return str((((gltf.meshes[mesh].extras or {}).get("sssbake") or {}).get("lpv") or {}).get("field", "homogeneous"))


def _material(gltf: pygltflib.GLTF2, index: int | None, path: Path) -> Material:
    data = None
    if index is not None:
        data = ((gltf.materials[index].extras or {}).get("sssbake") or {}).get("material")
    if not data:
        raise ValueError(f"verify: {path}: a scattering primitive's material has no extras.sssbake.material")
    return Material(data["name"], tuple(data["sigma_s_prime"]), tuple(data["sigma_a"]), float(data["eta"]))


def _bake_report(path: Path) -> dict:
    report = path.with_suffix(".report.json")
    try:
        return json.loads(report.read_text())
    except (OSError, ValueError):
        return {}
