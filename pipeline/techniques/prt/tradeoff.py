"""``sssbake tradeoff``: what each prt knob buys, measured the way Hao & Varshney 2004 do
(image RMSE on [0, 1] values against images of the uncompressed q, Figs 5 and 9), with bytes per
vertex and seconds, written as JSON, CSV and Pareto plots.

One mesh (the largest of the file), one material. Test lights are random directions (seeded), not
in the direction set; "exact" images use q computed for the test direction itself with the same
gather, so the K sweep measures direction interpolation alone and the compression sweeps measure
compression alone (against the interpolated uncompressed q at K = `k`).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.directions import direction_set, interpolation_weights
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.scatter_operator import SCATTER_DEFAULTS, scatter_operator
from sssbake.pipeline.core.visibility import direction_visibility
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.render.sweep import (
    image_exposure,
    lit_images,
    per_vertex_size,
    random_lights,
    save_figure,
    tradeoff_result,
    worst_rmse,
)
from sssbake.pipeline.techniques.prt.compress import (
    PRT_COMPRESS_DEFAULTS,
    WEIGHTS,
    PrtCompressOptions,
    bytes_per_vertex,
    compress_prt,
    evaluate,
)
from sssbake.pipeline.techniques.prt.precompute import irradiance_signal

KS = (25, 50, 100, 200, 400)
ORDERS = (1, 2, 3, 4, 5, 6, 7, 8)
REFERENCE_FRACTIONS = (0.0025, 0.005, 0.01, 0.02, 0.05)


def prt_tradeoff(path: str | os.PathLike, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                 k: int = 200, ks=KS, orders=ORDERS, reference_fractions=REFERENCE_FRACTIONS, lights: int = 3,
                 size: int = 256, seed: int = 0) -> dict:
    """Run the sweeps and write ``<stem>.tradeoff.prt.json``, ``.csv`` and ``.png`` into `out_dir`.

    Returns
    -------
    dict
        ``rows`` (one per configuration: ``sweep``, ``mode``, ``k``, ``sh_order``,
        ``reference_fraction``, ``weights``, ``tables``, ``refine``, ``bytes_per_vertex``, ``seconds``, ``rmse_image``),
        ``frame_ms_sss``, ``frame_ms_plain``, ``frame_ratio``, ``vertices``, ``outputs``.
    """
    from sssbake.pipeline.render.renderer import Renderer, fit_camera

    path = Path(path)
    clean = clean_scene(load_scene(str(path)))
    surface = max(clean.surfaces, key=lambda s: len(s.positions))
    x_mm = surface.positions * mm_per_unit
    t = time.perf_counter()
    operator = scatter_operator(x_mm, surface.faces, surface.normals, profile_for(material),
                                SCATTER_DEFAULTS)
    operator_seconds = time.perf_counter() - t

    def gather(directions: np.ndarray) -> np.ndarray:
        visible = direction_visibility(surface.positions, surface.faces, surface.normals, directions)
        return operator.apply(irradiance_signal(surface.normals, directions, visible, material.eta))

    test = random_lights(lights, seed)
    exact = gather(test)  # (3, n, lights)

    renderer = Renderer((size, size))
    camera = fit_camera(surface.positions)
    base = dict(positions=surface.positions, normals=surface.normals, faces=surface.faces, model=np.eye(4),
                eta=material.eta)

    def images(q_per_light: list[np.ndarray]) -> list[np.ndarray]:
        return [image for image, _ in lit_images(renderer, camera, base, test, q_per_light)]

    reference_images = images([exact[:, :, j] for j in range(lights)])
    exposure = image_exposure(reference_images)

    def rmse_against(reference: list[np.ndarray], q_per_light: list[np.ndarray]) -> float:
        return worst_rmse(images(q_per_light), reference, exposure)

    rows = []
    uncompressed = None
    for kk in sorted(set(ks) | {k}):
        t = time.perf_counter()
        ds = direction_set(kk)
        q = gather(ds.directions)
        seconds = time.perf_counter() - t + operator_seconds
        index, weights = interpolation_weights(ds, test)
        interpolated = [np.einsum("cna,a->cn", q[:, :, index[j]], weights[j]) for j in range(lights)]
        if kk in ks:
            rows.append({"sweep": "directions", "mode": "float", "k": kk, "sh_order": 0, "reference_fraction": 1.0,
                         "weights": "", "tables": "", "refine": 0.0, "bytes_per_vertex": 12.0 * kk, "seconds": seconds,
                         "rmse_image": rmse_against(reference_images, interpolated)})
        if kk == k:
            uncompressed = (ds, q, seconds, images(interpolated))

    ds, q, precompute_seconds, target = uncompressed
    configs = [("quantization", PrtCompressOptions(mode="lloyd"))]
    configs += [("sh", PrtCompressOptions(mode="sh", sh_order=n)) for n in orders]
    # The fraction sweep measures fractions: no floor on the reference count.
    # shared tables against RGB ones (the default "auto" picks one of them per mesh)
    configs += [("reference_points", PrtCompressOptions(reference_fraction=f, sh_order=n, weights=w, reference_floor=0,
                                                        tables="shared"))
                for f in reference_fractions for n in (0, 2, 3) for w in WEIGHTS]
    configs += [("reference_points", PrtCompressOptions(reference_fraction=f, reference_floor=0, **change))
                for f in reference_fractions for change in ({"tables": "rgb"}, {"refine": 0.0})]
    default_prt = None
    for sweep, options in configs:
        t = time.perf_counter()
        prt = compress_prt(q, ds, surface.positions, surface.faces, material.eta, options)
        seconds = precompute_seconds + time.perf_counter() - t
        decoded = [evaluate(prt, test[j]) for j in range(lights)]
        rows.append({"sweep": sweep, "mode": options.mode, "k": k, "sh_order": prt.sh_order,
                     "reference_fraction": options.reference_fraction if options.mode == "refs+sh" else 0.0,
                     "weights": options.weights if options.mode == "refs+sh" else "",
                     "tables": ("shared" if len(prt.ref_scale) else "rgb") if options.mode == "refs+sh" else "",
                     "refine": options.refine if options.mode == "refs+sh" else 0.0,
                     "bytes_per_vertex": bytes_per_vertex(prt)["total"], "seconds": seconds,
                     "rmse_image": rmse_against(target, decoded)})
        if options == PrtCompressOptions():
            default_prt = prt
    if default_prt is None:
        default_prt = compress_prt(q, ds, surface.positions, surface.faces, material.eta)

    return tradeoff_result("prt", path, out_dir, rows, renderer, camera, base, [{**base, "prt": default_prt}],
                           len(surface.positions), material, mm_per_unit, test, _plot)


def _plot(rows: list[dict], path: str) -> None:
    """The Pareto plots: RMSE against K, against the reference fraction, against bytes per vertex and
    against bake seconds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(20, 4.5))
    k_rows = [r for r in rows if r["sweep"] == "directions"]
    axes[0].plot([r["k"] for r in k_rows], [r["rmse_image"] for r in k_rows], "o-")
    axes[0].set(xlabel="light directions K", ylabel="image RMSE", title="interpolation over directions (cf. Fig. 5)")
    for n in (0, 2, 3):
        for w, style in (("barycentric", "o-"), ("least_squares", "s--"), ("best_fit", "d:")):
            sel = [r for r in rows if r["sweep"] == "reference_points" and r["sh_order"] == n and r["weights"] == w
                   and r["tables"] == "shared" and r["refine"] == PRT_COMPRESS_DEFAULTS.refine]
            axes[1].plot([r["reference_fraction"] for r in sel], [r["rmse_image"] for r in sel], style,
                         label=f"SH n={n}, {w}")
    for label, pick, style in (("RGB tables", lambda r: r["tables"] == "rgb", "x-"),
                               ("no refinement", lambda r: r["refine"] == 0.0, "+-")):
        sel = [r for r in rows if r["sweep"] == "reference_points" and pick(r)]
        axes[1].plot([r["reference_fraction"] for r in sel], [r["rmse_image"] for r in sel], style, label=label)
    axes[1].set(xscale="log", xlabel="reference points / vertices", ylabel="image RMSE",
                title="reference points + SH (cf. Fig. 9)")
    axes[1].legend(fontsize=8)
    for sweep, marker in (("quantization", "*"), ("sh", "^"), ("reference_points", "o"), ("directions", "x")):
        sel = [r for r in rows if r["sweep"] == sweep]
        axes[2].scatter([r["bytes_per_vertex"] for r in sel], [r["rmse_image"] for r in sel], marker=marker, label=sweep)
    compressed = sorted((r for r in rows if r["sweep"] != "directions"), key=lambda r: r["bytes_per_vertex"])
    front, best = [], np.inf
    for r in compressed:
        if r["rmse_image"] < best:
            best = r["rmse_image"]
            front.append(r)
    axes[2].plot([r["bytes_per_vertex"] for r in front], [r["rmse_image"] for r in front], "k-", lw=1, label="Pareto front")
    axes[2].set(xscale="log", yscale="log", xlabel="bytes per vertex (RGB, all)", ylabel="image RMSE",
                title="accuracy vs storage")
    axes[2].legend(fontsize=8)
    for sweep, marker in (("quantization", "*"), ("sh", "^"), ("reference_points", "o"), ("directions", "x")):
        sel = [r for r in rows if r["sweep"] == sweep]
        axes[3].scatter([r["seconds"] for r in sel], [r["rmse_image"] for r in sel], marker=marker, label=sweep)
    axes[3].set(yscale="log", xlabel="bake seconds (precompute + compress)", ylabel="image RMSE",
                title="accuracy vs bake time")
    axes[3].legend(fontsize=8)
    save_figure(fig, path)


class PrtTradeoff:
    """``sssbake tradeoff --technique prt`` (`technique.Technique`'s tradeoff hooks)."""

    def run_tradeoff(self, path: Path, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                     args: argparse.Namespace) -> dict:
        return prt_tradeoff(path, mm_per_unit, material, out_dir, k=args.k, lights=args.lights, size=args.size)

    def tradeoff_row(self, row: dict) -> str:
        return (f"{row['mode']:>8} K={row['k']:<4} n={row['sh_order']} refs={row['reference_fraction']:<7g} "
                f"{row['weights']:<13} {per_vertex_size(row)}")
