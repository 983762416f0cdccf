"""``sssbake tradeoff --technique spectral``: what the knobs of Patro 2007's subsurface normals buy,
measured as the other tradeoffs measure it (`tradeoff`): image RMSE on [0, 1] values against
images of the exact offline reference (`reference.reference_scattering`), with bytes per vertex as
stored and precompute seconds, written as JSON, CSV and plots.

One mesh (the largest of the file), one material, random test lights (seeded). The runtime is the
plain Lambert shader fed another normal field, so every image is Lambert of its normals (clamped
cosine times shadow visibility, drawn as q on the welded surface, as ``verify`` draws its
baseline) times one per-channel least-squares scale fitted over all the test lights at once: a
normal field moves light across the surface, the scale stands for the material's albedo. Rows:
plain Lambert (the file's normals, the baseline), the default configuration
(`SPECTRAL_DEFAULTS`), then one sweep per knob: the harmonics m (one eigensolve each), the filter
width as multiples of the material's (re-filtering the default's spectrum, no new eigensolve)
and the naive normals' α.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.naive_normals import naive_normals
from sssbake.pipeline.core.visibility import direction_visibility
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.render.image_metrics import best_fit_scale
from sssbake.pipeline.render.items import PLAIN_ALBEDO
from sssbake.pipeline.render.sweep import (
    lit_images,
    per_vertex_size,
    reference_lights,
    reference_views,
    save_figure,
    tradeoff_result,
    worst_rmse,
)
from sssbake.pipeline.techniques.spectral.layout import NORMAL_BYTES
from sssbake.pipeline.techniques.spectral.precompute import (
    SPECTRAL_DEFAULTS,
    SpectralPrecomputeOptions,
    naive_parameters,
    precompute_spectral,
)

EIGENPAIRS = (50, 100, 200, 300, 500)
WIDTH_FACTORS = (0.25, 0.5, 1.0, 2.0, 4.0)
ALPHAS = (0.1, 0.5, 1.0, 2.0)
#: The swept knobs, in sweep order, and the row key each sets.
SWEEPS = (("eigenpairs", "eigenpairs"), ("width", "width_factor"), ("naive_alpha", "alpha"))


def spectral_tradeoff(path: str | os.PathLike, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                      eigenpairs=EIGENPAIRS, width_factors=WIDTH_FACTORS, alphas=ALPHAS, lights: int = 3,
                      size: int = 256, seed: int = 0, options: SpectralPrecomputeOptions = SPECTRAL_DEFAULTS) -> dict:
    """Run the sweeps and write ``<stem>.tradeoff.spectral.json``, ``.csv`` and ``.png`` into `out_dir`.

    Parameters
    ----------
    path, mm_per_unit, material, out_dir, lights, size, seed
        As `kernels_tradeoff.kernels_tradeoff`'s.
    eigenpairs, width_factors, alphas : sequences
        The values of the m sweep, the filter width sweep (multiples of the default
        configuration's width) and the naive α sweep.
    options : SpectralPrecomputeOptions
        The default configuration.

    Returns
    -------
    dict
        ``rows`` (``sweep``: ``"plain"``, ``"default"``, ``"eigenpairs"``, ``"width"`` or
        ``"naive_alpha"``; ``normals`` (``"file"``, ``"spectral"``, ``"naive"``), ``eigenpairs``
        (as solved; 0 where none), ``width_factor``, ``width_mm``, ``alpha``, ``bytes_per_vertex``,
        ``seconds``, ``rmse_image``, ``scale`` (3,), the per-channel fit), ``frame_ms_sss`` (the
        plain shader with the default's normals), ``frame_ms_plain`` (with the file's),
        ``frame_ratio``, ``asset``, ``vertices``, ``material``, ``mm_per_unit``, ``lights``,
        ``image_size``, ``outputs``.
    """
    path = Path(path)
    clean = clean_scene(load_scene(str(path)))
    surface = max(clean.surfaces, key=lambda s: len(s.positions))

    test, reference = reference_lights(surface, mm_per_unit, material, lights, seed)  # each (3, n)
    visible = direction_visibility(surface.positions, surface.faces, surface.normals, test)  # (n, lights)

    views = reference_views(surface, material, test, reference, size)
    renderer, camera, base, exposure = views.renderer, views.camera, views.base, views.exposure
    reference_images, masks = views.images, views.masks

    def measure(normals: np.ndarray) -> dict:
        """``rmse_image`` and ``scale`` of Lambert with unit `normals` (n, 3)."""
        lambert = np.clip(normals @ test.T, 0.0, None) * visible  # (n, lights)
        images = [im for im, _ in lit_images(renderer, camera, base, test,
                                             [np.repeat(lambert[None, :, j], 3, axis=0) for j in range(lights)])]
        scale = best_fit_scale(np.concatenate(images), np.concatenate(reference_images), np.concatenate(masks))
        return {"rmse_image": worst_rmse([im * scale for im in images], reference_images, exposure),
                "scale": scale.tolist()}

    def spectral_row(sweep: str, pre, factor: float, normals: np.ndarray, seconds: float) -> dict:
        return {"sweep": sweep, "normals": "spectral", "eigenpairs": pre.stats["eigenpairs"], "width_factor": factor,
                "width_mm": float(pre.width_mm * factor), "alpha": 0.0, "bytes_per_vertex": NORMAL_BYTES,
                "seconds": seconds, **measure(normals)}

    def solve(opts: SpectralPrecomputeOptions):
        """The precompute and its seconds (a bake of spectral normals)."""
        pre = precompute_spectral(surface, mm_per_unit, material, opts)
        return pre, sum(pre.seconds.values())

    rows = [{"sweep": "plain", "normals": "file", "eigenpairs": 0, "width_factor": 0.0, "width_mm": 0.0, "alpha": 0.0,
             "bytes_per_vertex": 0.0, "seconds": 0.0, **measure(surface.normals)}]
    default, default_seconds = solve(options)
    default_row = spectral_row("default", default, 1.0, default.normals, default_seconds)
    rows.append(default_row)
    for m in eigenpairs:
        if m == options.eigenpairs:
            rows.append({**default_row, "sweep": "eigenpairs"})
            continue
        pre, seconds = solve(replace(options, eigenpairs=m))
        rows.append(spectral_row("eigenpairs", pre, 1.0, pre.normals, seconds))
    for factor in width_factors:
        t = time.perf_counter()
        normals, _ = default.spectrum.filtered(default.width_mm * factor)
        seconds = default_seconds - default.seconds["filter"] + time.perf_counter() - t
        rows.append(spectral_row("width", default, factor, normals, seconds))
    x_mm = surface.positions * mm_per_unit
    sigma_tr, radius_mm = naive_parameters(material)
    for alpha in alphas:
        t = time.perf_counter()
        normals = naive_normals(x_mm, surface.normals, sigma_tr, alpha, radius_mm)
        rows.append({"sweep": "naive_alpha", "normals": "naive", "eigenpairs": 0, "width_factor": 0.0,
                     "width_mm": 0.0, "alpha": alpha, "bytes_per_vertex": NORMAL_BYTES,
                     "seconds": time.perf_counter() - t, **measure(normals)})

    result = tradeoff_result("spectral", path, out_dir, rows, renderer, camera, base,
                             [{**base, "normals": default.normals, "albedo": PLAIN_ALBEDO}], len(surface.positions),
                             material, mm_per_unit, test, _plot)
    renderer.release()
    return result


def _plot(rows: list[dict], path: str) -> None:
    """Image RMSE against each knob (the plain-Lambert baseline dashed), and against bake seconds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plain = next(r["rmse_image"] for r in rows if r["sweep"] == "plain")
    fig, axes = plt.subplots(1, len(SWEEPS) + 1, figsize=(4.5 * (len(SWEEPS) + 1), 4.2))
    for ax, (sweep, knob) in zip(axes, SWEEPS):
        sel = [r for r in rows if r["sweep"] == sweep]
        ax.plot([r[knob] for r in sel], [r["rmse_image"] for r in sel], "o-", label=sweep.replace("_", " "))
        ax.axhline(plain, color="k", ls="--", lw=1, label="plain Lambert")
        ax.set(xlabel=knob.replace("_", " "), ylabel="image RMSE", title=f"{sweep.replace('_', ' ')} sweep")
        ax.legend(fontsize=8)
    for normals, marker in (("spectral", "o"), ("naive", "^")):
        sel = [r for r in rows if r["normals"] == normals]
        axes[-1].scatter([r["seconds"] for r in sel], [r["rmse_image"] for r in sel], marker=marker, label=normals)
    axes[-1].axhline(plain, color="k", ls="--", lw=1, label="plain Lambert")
    axes[-1].set(xlabel="precompute seconds", ylabel="image RMSE", title="accuracy vs bake time")
    axes[-1].legend(fontsize=8)
    save_figure(fig, path)


class SpectralTradeoff:
    """``sssbake tradeoff --technique spectral`` (`technique.Technique`'s tradeoff hooks)."""

    def run_tradeoff(self, path: Path, mm_per_unit: float, material: Material, out_dir: str | os.PathLike,
                     args: argparse.Namespace) -> dict:
        return spectral_tradeoff(path, mm_per_unit, material, out_dir, lights=args.lights, size=args.size)

    def tradeoff_row(self, row: dict) -> str:
        return (f"{row['normals']:>8} m={row['eigenpairs']:<4} width x{row['width_factor']:<5g} "
                f"alpha={row['alpha']:<4g} {per_vertex_size(row)}")
