"""Shared parts of the ``sssbake tradeoff`` sweeps: test lights, reference images, sweep rows,
worst-light RMSE, the JSON, CSV and plot each sweep writes, and the pieces of their CLI."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sssbake.exporters.atomic import atomic_path
from sssbake.pipeline.core.materials import Material
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.render.image_metrics import rmse
from sssbake.pipeline.render.items import PLAIN_ALBEDO

#: Above this many welded vertices the other techniques' tradeoffs sum the reference's far sources
#: through clusters (~1e-3 of q; the exact sum would take tens of minutes).
CLUSTERED_ABOVE = 30000


def tradeoff_result(technique: str, path: Path, out_dir: str | os.PathLike, rows: list[dict], renderer, camera,
                    base: dict, runtime: list[dict], vertices: int, material: Material, mm_per_unit: float,
                    lights: np.ndarray, plot, extra: dict | None = None) -> dict:
    """A tradeoff's result with its frame times, written as ``<stem>.tradeoff.<technique>.json``,
    ``.csv`` and ``.png`` into `out_dir` (`write_outputs`).

    Parameters
    ----------
    rows : list of dict
    renderer : render.Renderer
    camera : render.Camera
    base : dict
        The render item without its data (see `lit_images`): with `PLAIN_ALBEDO`, the plain
        shader the frame times are compared with.
    runtime : list of dict
        The items the technique's runtime draws (its default configuration).
    vertices : int
        The welded surface's vertex count.
    lights : (m, 3) float64
        The test lights (frames are timed under the first).
    plot : callable
        ``plot(rows, path)`` (`write_outputs`).
    extra : dict, optional
        More keys of the result.
    """
    from sssbake.pipeline.render.renderer import RenderLight

    light = RenderLight(False, tuple(lights[0]), 1.0)
    frame_sss = renderer.frame_ms(runtime, camera, light)
    frame_plain = renderer.frame_ms([{**base, "albedo": PLAIN_ALBEDO}], camera, light)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = out_dir / f"{path.stem}.tradeoff.{technique}"
    result = {"asset": str(path), "vertices": vertices, "material": material.name,
              "mm_per_unit": mm_per_unit, "lights": lights.tolist(), "image_size": list(renderer.size), "rows": rows,
              "frame_ms_sss": frame_sss, "frame_ms_plain": frame_plain,
              "frame_ratio": frame_sss / max(frame_plain, 1e-9),
              "outputs": {"json": f"{stem}.json", "csv": f"{stem}.csv", "plot": f"{stem}.png"}, **(extra or {})}
    write_outputs(result, stem, plot)
    return result


def random_lights(lights: int, seed: int) -> np.ndarray:
    """(lights, 3) float64 random unit directions towards the test lights (seeded)."""
    rng = np.random.default_rng(seed)
    test = rng.normal(size=(lights, 3))
    return test / np.linalg.norm(test, axis=1, keepdims=True)


def reference_lights(surface, mm_per_unit: float, material: Material, lights: int,
                     seed: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """The test lights of the technique tradeoffs and the offline reference under each.

    Parameters
    ----------
    surface : clean.Surface
    lights : int
        Random unit directions (seeded with `seed`).

    Returns
    -------
    test : (lights, 3) float64
    reference : list of (3, n) float64
        `reference.reference_scattering` per light: the exact sum, or through clusters above
        `CLUSTERED_ABOVE` vertices.
    """
    test = random_lights(lights, seed)
    clustered = len(surface.positions) > CLUSTERED_ABOVE
    return test, [reference_scattering(surface, mm_per_unit, material, Light("directional", tuple(d)),
                                       clustered=clustered) for d in test]


@dataclass(frozen=True, eq=False)
class ReferenceViews:
    """A welded surface drawn from one camera under each test light with the reference's q.

    Attributes
    ----------
    renderer : render.Renderer
    camera : render.Camera
    base : dict
        The render item without its data (`lit_images`).
    images : list of (H, W, 3) float32
    masks : list of (H, W) bool
    exposure : float
        `image_exposure` of the images.
    """

    renderer: object
    camera: object
    base: dict
    images: list
    masks: list
    exposure: float


def reference_views(surface, material: Material, lights: np.ndarray, reference: list[np.ndarray],
                    size: int) -> ReferenceViews:
    """`ReferenceViews` of `surface` (a fitted camera, `size`² images) under the (m, 3) `lights`
    with `reference` (`reference_lights`)."""
    from sssbake.pipeline.render.renderer import Renderer, fit_camera

    renderer = Renderer((size, size))
    camera = fit_camera(surface.positions)
    base = dict(positions=surface.positions, normals=surface.normals, faces=surface.faces, model=np.eye(4),
                eta=material.eta)
    drawn = lit_images(renderer, camera, base, lights, reference)
    images = [im for im, _ in drawn]
    return ReferenceViews(renderer, camera, base, images, [m for _, m in drawn], image_exposure(images))


def sweep_rows(default_row: dict, default: tuple, sweeps, measure) -> list[dict]:
    """The default's row (``sweep = "default"``), then one row per configuration of each sweep
    (``[(name, [configuration, ...]), ...]``), the default's configuration reusing its row and
    the others measured by ``measure(*configuration)[0]``."""
    rows = [{"sweep": "default", **default_row}]
    for sweep, configs in sweeps:
        for config in configs:
            row = default_row if config == default else measure(*config)[0]
            rows.append({"sweep": sweep, **row})
    return rows


def lit_images(renderer, camera, base: dict, lights: np.ndarray,
               q_per_light: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Render one surface under each directional light with its per-vertex scattered radiance.

    Parameters
    ----------
    renderer : render.Renderer
    camera : render.Camera
    base : dict
        A render item without its radiance (``positions``, ``normals``, ``faces``, ``model``, ``eta``).
    lights : (m, 3) float64
        Unit directions towards the lights, irradiance 1.
    q_per_light : list of m (3, n) float64
        q at the vertices for each light.

    Returns
    -------
    list of m (image (H, W, 3) float32, coverage (H, W) bool)
    """
    from sssbake.pipeline.render.renderer import RenderLight

    return [renderer.render([{**base, "q": q.T}], camera, RenderLight(False, tuple(lights[j]), 1.0))
            for j, q in enumerate(q_per_light)]


def image_exposure(reference: list[np.ndarray]) -> float:
    """One exposure for a set of views: the brightest view's 99.5th-percentile pixel (brightest
    channel, all pixels) maps to 1."""
    return 1.0 / max(max(float(np.percentile(im.max(axis=-1), 99.5)) for im in reference), 1e-300)


def worst_rmse(images: list[np.ndarray], reference: list[np.ndarray], exposure: float,
               masks: list[np.ndarray] | None = None) -> float:
    """The paper's metric, image RMSE on [0, 1] values, the worst over the views: over whole images,
    or over the (H, W) bool `masks` (e.g. the object's pixels) when given."""
    masks = masks if masks is not None else [None] * len(images)
    return max(rmse(a, b, exposure, m) for a, b, m in zip(images, reference, masks))


def write_outputs(result: dict, stem: Path, plot) -> None:
    """``stem.json`` (the result), ``stem.csv`` (its rows) and ``stem.png`` (``plot(rows, path)``),
    each written atomically."""
    rows = result["rows"]
    with atomic_path(f"{stem}.json") as tmp:
        Path(tmp).write_text(json.dumps(result, indent=1))
    with atomic_path(f"{stem}.csv") as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot(rows, f"{stem}.png")


def per_vertex_size(row: dict) -> str:
    """A tradeoff row's size column for a technique that stores data per vertex."""
    return f"{row['bytes_per_vertex']:9.1f} B/vertex"


def save_figure(fig, path) -> None:
    """Write a sweep's matplotlib `fig` to the PNG at `path` (atomically) and free it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    plt.close(fig)
