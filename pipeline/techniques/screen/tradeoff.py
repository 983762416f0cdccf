"""``sssbake tradeoff --technique screen``: what the screen technique's knobs (Mertens et al. 2003)
cost and buy, measured as the other tradeoffs measure it (`tradeoff`): image RMSE on [0, 1] values
against images of the exact offline reference (`reference.reference_scattering`), with the frame
time of each configuration in the reference runtime (the cost users pay: the tables are a few KB
per material and nothing is baked per vertex), written as JSON, CSV and plots.

One mesh (the largest of the file), one material, random test lights (seeded). A default
configuration (`SCREEN_DEFAULTS`, `SCREEN_RUNTIME_DEFAULTS`), then one sweep per knob that changes
that knob alone: importance samples N, uniform samples U, and the runtime's Jacobian, fill and
interleaving. Every configuration is rendered by the GLSL passes, so the RMSE holds what the
runtime does: shadow-map visibility, the camera's view of the surface, missing surface.
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
from sssbake.pipeline.mesh.subdivide import subdivided_surface
from sssbake.pipeline.render.sweep import (
    reference_lights,
    reference_views,
    save_figure,
    sweep_rows,
    tradeoff_result,
    worst_rmse,
)
from sssbake.pipeline.techniques.screen.entry import SAMPLES, UNIFORM
from sssbake.pipeline.techniques.screen.layout import screen_bytes, screen_tables
from sssbake.pipeline.techniques.screen.runtime import SCREEN_RUNTIME_DEFAULTS, ScreenRuntimeOptions
from sssbake.pipeline.techniques.screen.samples import SCREEN_DEFAULTS, ScreenSamplesOptions, screen_samples

#: The runtime sweep: each changes one runtime option from the default.
RUNTIME_CHANGES = ({"jacobian": True}, {"fill": False}, {"interleave": 1})


def screen_tradeoff(path: str | os.PathLike, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                    samples=SAMPLES, uniform=UNIFORM, runtime_changes=RUNTIME_CHANGES, lights: int = 3,
                    size: int = 256, seed: int = 0,
                    options: ScreenSamplesOptions = SCREEN_DEFAULTS,
                    runtime: ScreenRuntimeOptions = SCREEN_RUNTIME_DEFAULTS, frames: int = 10,
                    reference_subdivisions: int = 0) -> dict:
    """Run the sweeps and write ``<stem>.tradeoff.screen.json``, ``.csv`` and ``.png`` into `out_dir`.

    Parameters
    ----------
    path, mm_per_unit, material, out_dir, lights, size, seed
        As `kernels_tradeoff.kernels_tradeoff`'s.
    samples, uniform : sequences
        The values of the N and U sweeps.
    runtime_changes : sequence of dict
        The runtime sweep: each a change of `runtime`'s fields.
    options, runtime : ScreenSamplesOptions, ScreenRuntimeOptions
        The default configuration.
    frames : int
        Frames timed per configuration.
    reference_subdivisions : int
        Midpoint subdivisions of the surface the reference is computed and drawn on
        (`subdivide.subdivided_surface`): the screen technique shades per pixel, a per-vertex
        reference only as finely as the vertices are spaced.

    Returns
    -------
    dict
        ``rows`` (the default first, ``sweep = "default"``, then ``"samples"``, ``"uniform"``,
        ``"runtime"``: ``samples``, ``uniform``, ``jacobian``, ``fill``, ``interleave``,
        ``bytes`` (the material's tables), ``bytes_per_vertex`` (0), ``seconds`` (the tables'
        precompute), ``frame_ms``, ``rmse_image`` (worst over the lights), ``rmse_image_per_light``,
        ``rmse_object`` (the worst over the object's pixels)), ``frame_ms_sss`` (the default), ``frame_ms_plain``,
        ``frame_ratio``, ``asset``, ``vertices``, ``material``, ``mm_per_unit``, ``lights``,
        ``image_size``, ``outputs``, ``reference_vertices``, ``lights_towards_camera`` (each light's
        cosine to the direction of the camera).
    """
    from sssbake.pipeline.render.renderer import RenderLight

    path = Path(path)
    clean = clean_scene(load_scene(str(path)))
    surface = max(clean.surfaces, key=lambda s: len(s.positions))

    fine = subdivided_surface(surface, reference_subdivisions)
    test, reference = reference_lights(fine, mm_per_unit, material, lights, seed)
    views = reference_views(fine, material, test, reference, size)
    renderer, camera, exposure = views.renderer, views.camera, views.exposure
    reference_images, masks = views.images, views.masks
    base = dict(positions=surface.positions, normals=surface.normals, faces=surface.faces, model=np.eye(4),
                eta=material.eta)
    # back-lit views (light from behind the object) are where screen space misses most
    towards_camera = np.asarray(camera.eye) - 0.5 * (surface.positions.min(axis=0) + surface.positions.max(axis=0))
    towards_camera /= np.linalg.norm(towards_camera)

    def measure(opts: ScreenSamplesOptions, run: ScreenRuntimeOptions) -> tuple[dict, dict]:
        t = time.perf_counter()
        tables = screen_samples(material, opts)
        seconds = time.perf_counter() - t
        item = {**base, "screen": tables, "mm_per_unit": mm_per_unit, "screen_runtime": run}
        images = [renderer.render([item], camera, RenderLight(False, tuple(d), 1.0)) for d in test]
        row = {"samples": opts.samples, "uniform": opts.uniform, "jacobian": run.jacobian, "fill": run.fill,
               "interleave": run.interleave, "bytes": screen_bytes(screen_tables(tables, opts))["total"],
               "bytes_per_vertex": 0.0, "seconds": seconds,
               "frame_ms": renderer.frame_ms([item], camera, RenderLight(False, tuple(test[0]), 1.0), frames),
               "rmse_image": worst_rmse([im for im, _ in images], reference_images, exposure),
               "rmse_image_per_light": [worst_rmse([im], [ref], exposure)
                                        for (im, _), ref in zip(images, reference_images)],
               "rmse_object": worst_rmse([im for im, _ in images], reference_images, exposure,
                                         [m | mask for m, (_, mask) in zip(masks, images)])}
        return row, item

    default_row, default_item = measure(options, runtime)
    rows = sweep_rows(default_row, (options, runtime), [
        ("samples", [(replace(options, samples=n), runtime) for n in samples]),
        ("uniform", [(replace(options, uniform=u), runtime) for u in uniform]),
        ("runtime", [(options, replace(runtime, **change)) for change in runtime_changes])], measure)

    result = tradeoff_result("screen", path, out_dir, rows, renderer, camera, base, [default_item],
                             len(surface.positions), material, mm_per_unit, test, _plot,
                             {"reference_vertices": len(fine.positions),
                              "lights_towards_camera": (test @ towards_camera).tolist()})
    renderer.release()
    return result


def _plot(rows: list[dict], path: str) -> None:
    """Image RMSE against N and against frame time (every configuration, labelled)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for sweep, style in (("samples", "o-"), ("uniform", "s--")):
        sel = [r for r in rows if r["sweep"] == sweep]
        key = "samples" if sweep == "samples" else "uniform"
        axes[0].plot([r[key] for r in sel], [r["rmse_image"] for r in sel], style, label=f"{key} (N or U)")
    axes[0].set(xscale="log", yscale="log", xlabel="samples", ylabel="image RMSE", title="accuracy vs samples")
    axes[0].legend(fontsize=8)
    for r in rows:
        label = (f"N={r['samples']} U={r['uniform']}" + (" J" if r["jacobian"] else "") +
                 ("" if r["fill"] else " no fill") + ("" if r["interleave"] > 1 else " no interleave"))
        axes[1].scatter(r["frame_ms"], r["rmse_image"], marker="o")
        axes[1].annotate(label, (r["frame_ms"], r["rmse_image"]), textcoords="offset points", xytext=(4, 4),
                         fontsize=7)
    axes[1].set(yscale="log", xlabel="frame ms (reference runtime)", ylabel="image RMSE",
                title="accuracy vs frame time")
    save_figure(fig, path)


class ScreenTradeoff:
    """``sssbake tradeoff --technique screen`` (`technique.Technique`'s tradeoff hooks)."""

    def run_tradeoff(self, path: Path, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                     args: argparse.Namespace) -> dict:
        return screen_tradeoff(path, mm_per_unit, material, out_dir, samples=args.samples, uniform=args.uniform,
                               lights=args.lights, size=args.size, reference_subdivisions=args.reference_subdivisions)

    def tradeoff_row(self, row: dict) -> str:
        # screen stores nothing per vertex: its tables are per material
        return (f"N={row['samples']:<4} U={row['uniform']:<3} jacobian={row['jacobian']!s:<5} "
                f"fill={row['fill']!s:<5} interleave={row['interleave']:<2} {row['frame_ms']:8.2f} ms/frame "
                f"{row['bytes']:7d} B/material")
