"""``sssbake tradeoff --technique kernels``: what each knob of the kernels technique (Lensch et al.
2002) costs and buys, measured as the prt tradeoff measures it (`tradeoff`): image RMSE on [0, 1]
values against images of the exact offline reference (`reference.reference_scattering`), with
bytes as stored (the bake's kernel bits) and precompute seconds, written as JSON, CSV and plots.

One mesh (the largest of the file, all its primitives in one atlas, as the bake does), one
material, random test lights (seeded). A default configuration (`DEFAULT_RESOLUTION`,
`KERNELS_DEFAULTS`), then one sweep per knob that changes that knob alone: atlas resolution,
kernel size, F's threshold, blending (with and without the §5.4 optimisation, and none), seam
unfolding. Under F's byte bound (`kernels_f_bytes`, on by default) each source keeps its strongest
entries whatever the threshold, so the threshold sweep moves F only with ``f_bytes`` 0 in `options`.
Every configuration is rendered with the GPU runtime (`render`'s kernels draw), so the
RMSE holds everything the runtime does: shadow-map visibility, texel sampling, the bilinear read.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.mesh.atlas import compute_atlas
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.render.items import merged_primitive
from sssbake.pipeline.render.sweep import (
    image_exposure,
    lit_images,
    per_vertex_size,
    reference_lights,
    save_figure,
    sweep_rows,
    tradeoff_result,
    worst_rmse,
)
from sssbake.pipeline.techniques.kernels.entry import DEFAULT_RESOLUTION, RESOLUTIONS, SIZES, THRESHOLDS
from sssbake.pipeline.techniques.kernels.layout import kernels_bytes
from sssbake.pipeline.techniques.kernels.options import KernelsOptions
from sssbake.pipeline.techniques.kernels.options import BLENDS, KERNELS_DEFAULTS, SEAMS, KernelsPrecomputeOptions
from sssbake.pipeline.techniques.kernels.precompute import precompute_kernels

#: The swept knobs, in sweep order (each a row key).
KNOBS = ("atlas_resolution", "kernel_size", "threshold", "blend", "seams")


def kernels_tradeoff(path: str | os.PathLike, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                     resolutions=RESOLUTIONS, sizes=SIZES, thresholds=THRESHOLDS, blends=BLENDS, lights: int = 3,
                     size: int = 256, seed: int = 0, resolution: int = DEFAULT_RESOLUTION,
                     options: KernelsPrecomputeOptions = KERNELS_DEFAULTS) -> dict:
    """Run the sweeps and write ``<stem>.tradeoff.kernels.json``, ``.csv`` and ``.png`` into `out_dir`.

    Parameters
    ----------
    path : path
        A mesh file; its largest mesh (most welded vertices) is used.
    mm_per_unit : float
    material : Material
    out_dir : path
    resolutions, sizes, thresholds, blends : sequences
        The values of the atlas resolution, kernel size, threshold and blend sweeps.
    lights : int
        Random test lights; each row's RMSE is the worst over them.
    size : int
        Image width and height in pixels.
    seed : int
        Seed of the test lights.
    resolution : int
        Atlas resolution of the default configuration.
    options : KernelsPrecomputeOptions
        The default configuration's other knobs.

    Returns
    -------
    dict
        ``rows`` (the default first, ``sweep = "default"``, then one per sweep value: ``sweep``,
        ``atlas_resolution``, ``kernel_size``, ``threshold``, ``blend``, ``seams``, ``bytes``,
        ``bytes_per_vertex``, ``nnz``, ``seconds`` (precompute + atlas), ``atlas_seconds``,
        ``rmse_image``), ``frame_ms_sss`` (the default configuration), ``frame_ms_plain``,
        ``frame_ratio``, ``asset``, ``vertices``, ``material``, ``mm_per_unit``, ``lights``,
        ``image_size``, ``outputs``.
    """
    from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera

    path = Path(path)
    clean = clean_scene(load_scene(str(path)))
    mi = max(range(len(clean.surfaces)), key=lambda i: len(clean.surfaces[i].positions))
    surface, prims = clean.surfaces[mi], clean.scene.meshes[mi].primitives
    parts = [(p.positions, p.faces) for p in prims]
    render_vertices = [(p.positions, p.normals) for p in prims]

    test, reference = reference_lights(surface, mm_per_unit, material, lights, seed)  # each (3, n welded)

    renderer = Renderer((size, size))
    camera = fit_camera(surface.positions)
    # The reference is drawn on the file's own render vertices: the atlas only copies them.
    whole = merged_primitive(prims)
    welded = np.concatenate(surface.weld)
    base = dict(positions=whole.positions, normals=whole.normals, faces=whole.faces, model=np.eye(4),
                eta=material.eta)
    reference_images = [image for image, _ in lit_images(renderer, camera, base, test,
                                                         [q[:, welded] for q in reference])]
    exposure = image_exposure(reference_images)

    # One gutter for every atlas, wide enough for the largest kernel, so that the kernel-size
    # sweep changes the kernels alone.
    padding = max(4, (max([*sizes, options.kernel_size]) + 1) // 2)
    atlases = {}

    def atlas_for(res: int):
        if res not in atlases:
            t = time.perf_counter()
            atlas = compute_atlas(parts, res, padding)
            atlases[res] = (atlas, time.perf_counter() - t)
        return atlases[res]

    def draw_item(atlas, data) -> dict:
        cut = [replace(p, positions=p.positions[part.vmapping], normals=p.normals[part.vmapping], faces=part.faces,
                       uvs=(part.uvs,), tangents=None, colors=None) for p, part in zip(prims, atlas.parts)]
        merged = merged_primitive(cut)
        return dict(positions=merged.positions, normals=merged.normals, faces=merged.faces, model=np.eye(4),
                    eta=material.eta, kernels=data, uvs=merged.uvs[-1],
                    vertex_ids=np.concatenate([w[part.vmapping] for w, part in zip(surface.weld, atlas.parts)]))

    def measure(res: int, opts: KernelsPrecomputeOptions) -> tuple[dict, dict]:
        atlas, atlas_seconds = atlas_for(res)
        pre = precompute_kernels(surface, atlas, render_vertices, mm_per_unit, material, opts)
        item = draw_item(atlas, pre.data)
        images = [renderer.render([item], camera, RenderLight(False, tuple(d), 1.0))[0] for d in test]
        stored = kernels_bytes(pre.data, KernelsOptions().bits)
        row = {"atlas_resolution": res, "kernel_size": opts.kernel_size, "threshold": opts.threshold,
               "blend": opts.blend, "seams": opts.seams, "bytes": stored["total"],
               "bytes_per_vertex": stored["perVertex"], "nnz": pre.data.nnz,
               "seconds": sum(pre.seconds.values()) + atlas_seconds, "atlas_seconds": atlas_seconds,
               "rmse_image": worst_rmse(images, reference_images, exposure)}
        return row, item

    default_row, default_item = measure(resolution, options)
    rows = sweep_rows(default_row, (resolution, options), [
        ("atlas_resolution", [(res, options) for res in resolutions]),
        ("kernel_size", [(resolution, replace(options, kernel_size=k)) for k in sizes]),
        ("threshold", [(resolution, replace(options, threshold=th)) for th in thresholds]),
        ("blend", [(resolution, replace(options, blend=b)) for b in blends]),
        ("seams", [(resolution, replace(options, seams=s)) for s in SEAMS])], measure)

    result = tradeoff_result("kernels", path, out_dir, rows, renderer, camera, base, [default_item],
                             len(surface.positions), material, mm_per_unit, test, _plot)
    renderer.release()
    return result


def _plot(rows: list[dict], path: str) -> None:
    """One column per knob: image RMSE against bytes per vertex (top) and bake seconds (bottom),
    each point labelled with the knob's value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(KNOBS), figsize=(4.2 * len(KNOBS), 8), squeeze=False)
    for col, knob in enumerate(KNOBS):
        sel = [r for r in rows if r["sweep"] == knob]
        for ax, x, label in ((axes[0, col], "bytes_per_vertex", "bytes per vertex as stored"),
                             (axes[1, col], "seconds", "bake seconds (atlas + precompute)")):
            # a line only where the knob is a number (blend and seams are choices)
            ax.plot([r[x] for r in sel], [r["rmse_image"] for r in sel], "o" if knob in ("blend", "seams") else "o-")
            for r in sel:
                ax.annotate(f"{r[knob]:g}" if isinstance(r[knob], float) else str(r[knob]), (r[x], r["rmse_image"]),
                            textcoords="offset points", xytext=(4, 4), fontsize=8)
            ax.set(xlabel=label, ylabel="image RMSE", title=knob.replace("_", " "))
            ax.ticklabel_format(useOffset=False)
    save_figure(fig, path)


class KernelsTradeoff:
    """``sssbake tradeoff --technique kernels`` (`technique.Technique`'s tradeoff hooks)."""

    def run_tradeoff(self, path: Path, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                     args: argparse.Namespace) -> dict:
        return kernels_tradeoff(path, mm_per_unit, material, out_dir, resolutions=args.resolutions, sizes=args.sizes,
                                thresholds=args.thresholds, lights=args.lights, size=args.size,
                                resolution=args.atlas_resolution)

    def tradeoff_row(self, row: dict) -> str:
        return (f"atlas={row['atlas_resolution']:<5} k={row['kernel_size']:<2} threshold={row['threshold']:<6g} "
                f"{row['blend']:<9} seams={row['seams']:<6} {per_vertex_size(row)}")
