"""``sssbake tradeoff``: what each prt knob buys, measured the way Hao & Varshney 2004 do
(image RMSE on [0, 1] values against images of the uncompressed q, Figs 5 and 9), with bytes per
vertex and seconds, written as JSON, CSV and Pareto plots.

One mesh (the largest of the file), one material. Test lights are random directions (seeded), not
in the direction set; "exact" images use q computed for the test direction itself with the same
gather, so the K sweep measures direction interpolation alone and the compression sweeps measure
compression alone (against the interpolated uncompressed q at K = `k`).
"""

from __future__ import annotations

import csv
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..exporters.atomic import atomic_path
from .clean import clean_scene
from .dipole import DipoleParams
from .directions import direction_set, interpolation_weights
from .image_metrics import rmse
from .load import load_scene
from .materials import Material
from .prt_compress import PRT_COMPRESS_DEFAULTS, WEIGHTS, PrtCompressOptions, bytes_per_vertex, compress_prt, evaluate
from .prt_precompute import irradiance_signal
from .reference import Light, reference_scattering
from .scatter_operator import SCATTER_DEFAULTS, scatter_operator
from .verify import PLAIN_ALBEDO
from .visibility import direction_visibility

KS = (25, 50, 100, 200, 400)
ORDERS = (1, 2, 3, 4, 5, 6, 7, 8)
REFERENCE_FRACTIONS = (0.0025, 0.005, 0.01, 0.02, 0.05)
#: Above this many welded vertices the other techniques' tradeoffs sum the reference's far sources
#: through clusters (~1e-3 of q; the exact sum would take tens of minutes).
CLUSTERED_ABOVE = 30000


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
    from .render import Renderer, fit_camera

    path = Path(path)
    clean = clean_scene(load_scene(str(path)))
    surface = max(clean.surfaces, key=lambda s: len(s.positions))
    x_mm = surface.positions * mm_per_unit
    t = time.perf_counter()
    operator = scatter_operator(x_mm, surface.faces, surface.normals, DipoleParams.from_material(material),
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
    configs += [("reference_points", PrtCompressOptions(reference_fraction=f, sh_order=n, weights=w, reference_floor=0))
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
                     "tables": options.tables if options.mode == "refs+sh" else "",
                     "refine": options.refine if options.mode == "refs+sh" else 0.0,
                     "bytes_per_vertex": bytes_per_vertex(prt)["total"], "seconds": seconds,
                     "rmse_image": rmse_against(target, decoded)})
        if options == PrtCompressOptions():
            default_prt = prt
    if default_prt is None:
        default_prt = compress_prt(q, ds, surface.positions, surface.faces, material.eta)

    return tradeoff_result("prt", path, out_dir, rows, renderer, camera, base, [{**base, "prt": default_prt}],
                           len(surface.positions), material, mm_per_unit, test)


def tradeoff_result(technique: str, path: Path, out_dir: str | os.PathLike, rows: list[dict], renderer, camera,
                    base: dict, runtime: list[dict], vertices: int, material: Material, mm_per_unit: float,
                    lights: np.ndarray, plot=None, extra: dict | None = None) -> dict:
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
    plot : callable, optional
        ``plot(rows, path)`` (`write_outputs`).
    extra : dict, optional
        More keys of the result.
    """
    from .render import RenderLight

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
    from .render import Renderer, fit_camera

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
    from .render import RenderLight

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


def write_outputs(result: dict, stem: Path, plot=None) -> None:
    """``stem.json`` (the result), ``stem.csv`` (its rows) and ``stem.png`` (``plot(rows, path)``,
    prt's Pareto plots by default), each written atomically."""
    rows = result["rows"]
    with atomic_path(f"{stem}.json") as tmp:
        Path(tmp).write_text(json.dumps(result, indent=1))
    with atomic_path(f"{stem}.csv") as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (plot or _plot)(rows, f"{stem}.png")


def _plot(rows: list[dict], path: str) -> None:
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
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    plt.close(fig)
