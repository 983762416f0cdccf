"""``sssbake tradeoff --technique lpv``: what the lpv technique's knobs (Børlum et al. 2011) cost and
buy, measured as the other tradeoffs measure it (`tradeoff`): image RMSE on [0, 1] values, with
the frame time of each configuration in the reference runtime (the GLSL passes), the grid's bytes
and the bake's seconds, written as JSON, CSV and plots.

One mesh (the largest of the file), one material, random test lights (seeded). Every grid
resolution × step count is rendered by the GPU runtime. A homogeneous medium is compared with the
exact offline dipole reference (`reference.reference_scattering`); the dipole knows no
heterogeneous medium, so a veined one (``field="marble"``) is compared with its own finest
configuration (the largest resolution and step count): how far each configuration is from
converged, not from the truth.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.render.sweep import (
    image_exposure,
    lit_images,
    random_lights,
    reference_lights,
    save_figure,
    tradeoff_result,
    worst_rmse,
)
from sssbake.pipeline.techniques.lpv.calibrate import render_scales
from sssbake.pipeline.techniques.lpv.entry import RESOLUTIONS, STEPS
from sssbake.pipeline.techniques.lpv.grid import LPV_GRID_DEFAULTS, LpvGridOptions, homogeneous, voxelise
from sssbake.pipeline.techniques.lpv.layout import lpv_bytes, lpv_tables
from sssbake.pipeline.techniques.lpv.marble_field import MARBLE_DEFAULTS, MarbleOptions, marble_field
from sssbake.pipeline.techniques.lpv.matrices import propagation_matrices
from sssbake.pipeline.techniques.lpv.options import FIELDS
from sssbake.pipeline.techniques.lpv.propagate import LPV_DEFAULTS



def lpv_tradeoff(path: str | os.PathLike, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                 resolutions=RESOLUTIONS, steps=STEPS, field: str = "homogeneous",
                 marble: MarbleOptions = MARBLE_DEFAULTS, grid: LpvGridOptions = LPV_GRID_DEFAULTS, lights: int = 3,
                 size: int = 256, seed: int = 0, frames: int = 10) -> dict:
    """Run the sweep and write ``<stem>.tradeoff.lpv.json``, ``.csv`` and ``.png`` into `out_dir`.

    Parameters
    ----------
    path, mm_per_unit, material, out_dir, lights, size, seed
        As `kernels_tradeoff.kernels_tradeoff`'s.
    resolutions, steps : sequences
        Grid resolutions (cells along the longest side) and propagation steps; every pair is run.
    field : str
        ``"homogeneous"`` (against the dipole) or ``"marble"`` (veins of `marble` through
        `material`, against the finest configuration).
    grid : LpvGridOptions
        Padding and supersampling (its resolution is swept).
    frames : int
        Frames timed per configuration.

    Returns
    -------
    dict
        ``rows`` (``sweep`` ("grid"), ``resolution``, ``shape``, ``cell_mm``, ``steps``, ``bytes`` (the mesh's
        tables), ``bytes_per_vertex`` (0), ``seconds`` (voxelising and calibrating), ``frame_ms``,
        ``rmse_image`` (worst over the lights), ``rmse_image_per_light``, ``rmse_object``),
        ``reference`` (the profile model, e.g. ``"montecarlo"``, or the finest configuration), ``field``, ``frame_ms_sss`` (the
        finest configuration), ``frame_ms_plain``, ``frame_ratio``, ``asset``, ``vertices``,
        ``material``, ``mm_per_unit``, ``lights``, ``image_size``, ``outputs``.
    """
    from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera

    if field not in FIELDS:
        raise ValueError(f"lpv tradeoff: field must be 'homogeneous' or 'marble', got {field!r}")
    path = Path(path)
    clean = clean_scene(load_scene(str(path)))
    surface = max(clean.surfaces, key=lambda s: len(s.positions))
    renderer = Renderer((size, size))
    camera = fit_camera(surface.positions)
    base = dict(positions=surface.positions, normals=surface.normals, faces=surface.faces, model=np.eye(4),
                eta=material.eta)
    source = homogeneous(material) if field == "homogeneous" else marble_field(mm_per_unit,
                                                                                replace(marble, base=material))
    max_steps = max(steps)
    configs = []
    for res in sorted(resolutions):
        t = time.perf_counter()
        voxels = voxelise(surface, mm_per_unit, source, material.eta, replace(grid, resolution=res))
        scales = render_scales(voxels, max_steps, material.profile, material.escape_gain)
        seconds = time.perf_counter() - t
        stored = lpv_bytes(lpv_tables(voxels, propagation_matrices(), scales, field))["total"]
        configs += [(res, voxels, scales, seconds, stored, s) for s in sorted(steps)]

    rng_lights = random_lights(lights, seed)

    def item_of(voxels, scales, s) -> dict:
        return {**base, "lpv": voxels, "lpv_matrices": propagation_matrices(), "lpv_scales": scales, "lpv_steps": s,
                "lpv_shadow_size": LPV_DEFAULTS.shadow_size}

    def draw(item) -> list[tuple[np.ndarray, np.ndarray]]:
        return [renderer.render([item], camera, RenderLight(False, tuple(d), 1.0)) for d in rng_lights]

    if field == "homogeneous":
        _, reference = reference_lights(surface, mm_per_unit, material, lights, seed)
        drawn = lit_images(renderer, camera, base, rng_lights, reference)
        label = material.profile
    else:
        res, voxels, scales, _, _, s = configs[-1]
        drawn = draw(item_of(voxels, scales, s))
        label = f"lpv {res} x {s} steps"
    reference_images, masks = [im for im, _ in drawn], [m for _, m in drawn]
    exposure = image_exposure(reference_images)

    rows, finest = [], None
    for res, voxels, scales, seconds, stored, s in configs:
        item = item_of(voxels, scales, s)
        images = draw(item)
        rows.append({"sweep": "grid", "resolution": res, "shape": list(voxels.shape), "cell_mm": voxels.cell_mm, "steps": s,
                     "bytes": stored, "bytes_per_vertex": 0.0, "seconds": seconds,
                     "frame_ms": renderer.frame_ms([item], camera, RenderLight(False, tuple(rng_lights[0]), 1.0),
                                                   frames),
                     "rmse_image": worst_rmse([im for im, _ in images], reference_images, exposure),
                     "rmse_image_per_light": [worst_rmse([im], [ref], exposure)
                                              for (im, _), ref in zip(images, reference_images)],
                     "rmse_object": worst_rmse([im for im, _ in images], reference_images, exposure,
                                               [m | mask for m, (_, mask) in zip(masks, images)])})
        finest = item
    result = tradeoff_result("lpv", path, out_dir, rows, renderer, camera, base, [finest], len(surface.positions),
                             material, mm_per_unit, rng_lights, _plot, {"reference": label, "field": field})
    renderer.release()
    return result


def _plot(rows: list[dict], path: str) -> None:
    """Image RMSE against steps (one line per resolution) and against frame time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for res in sorted({r["resolution"] for r in rows}):
        sel = [r for r in rows if r["resolution"] == res]
        axes[0].plot([r["steps"] for r in sel], [r["rmse_image"] for r in sel], "o-", label=f"{res}³")
        axes[1].plot([r["frame_ms"] for r in sel], [r["rmse_image"] for r in sel], "o-", label=f"{res}³")
    axes[0].set(xscale="log", xlabel="propagation steps", ylabel="image RMSE", title="accuracy vs steps")
    axes[1].set(xscale="log", xlabel="frame ms (reference runtime)", ylabel="image RMSE",
                title="accuracy vs frame time")
    for ax in axes:
        ax.legend(fontsize=8)
    save_figure(fig, path)


class LpvTradeoff:
    """``sssbake tradeoff --technique lpv`` (`technique.Technique`'s tradeoff hooks)."""

    def run_tradeoff(self, path: Path, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                     args: argparse.Namespace) -> dict:
        return lpv_tradeoff(path, mm_per_unit, material, out_dir, resolutions=args.lpv_resolutions,
                            steps=args.lpv_steps, field=args.lpv_field, lights=args.lights, size=args.size)

    def tradeoff_row(self, row: dict) -> str:
        # lpv stores its grid per mesh, nothing per vertex
        return (f"grid={row['resolution']:<3} {'x'.join(map(str, row['shape'])):<11} cell {row['cell_mm']:6.2f} mm "
                f"steps={row['steps']:<3} {row['frame_ms']:9.2f} ms/frame {row['bytes']:9d} B/mesh")
