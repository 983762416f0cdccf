"""Tiny fixtures several test modules share."""

import csv
import json
from pathlib import Path

import numpy as np

from sssbake.pipeline.mesh.baked import Fallback

# A plausible marble-like fallback with distinct values in every field, so a field swapped on export shows.
FALLBACK = Fallback(
    base_color=(0.83, 0.79, 0.75),
    thickness_texture=None,
    thickness_factor=2.0,
    attenuation_color=(0.9, 0.8, 0.7),
    attenuation_distance=4.0,
    diffuse_transmission_factor=0.4,
    diffuse_transmission_color=(1.0, 0.95, 0.9),
    ior=1.5,
)


def plane(spacing: float, half: int) -> tuple[np.ndarray, np.ndarray, int]:
    """A regular triangulated square of (2·half + 1)² vertices in z = 0: positions, faces, centre index."""
    n = 2 * half + 1
    g = (np.arange(n) - half) * spacing
    xx, yy = np.meshgrid(g, g, indexing="ij")
    verts = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(n * n)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return verts, faces, half * n + half


def random_kernels(rng, n: int = 40, width: int = 24, height: int = 20, kernel_size: int = 7, texels: int = 150,
                   per_row: int = 6, borders: int = 5, surface: int | None = None):
    """Valid `KernelsData` with random values (n global vertices, `surface` welded surface
    vertices (default n, mapped one to one), a `width` × `height` atlas)."""
    from sssbake.pipeline.techniques.kernels.data import KernelsData

    k2 = kernel_size * kernel_size
    chosen = rng.choice(width * height, texels + borders, replace=False).astype(np.int64)
    pixels, border = np.sort(chosen[:texels]), np.sort(chosen[texels:])
    counts = rng.integers(0, per_row + 1, n)
    indptr = np.r_[0, np.cumsum(counts)].astype(np.int64)
    indices = np.concatenate([np.sort(rng.choice(n, c, replace=False)) for c in counts]).astype(np.int64)
    data = KernelsData(
        width=width, height=height, kernel_size=kernel_size, vertex_count=n, texels=pixels,
        kernels=rng.normal(0.0, 0.05, (texels, k2, 3)).astype(np.float32),
        texel_vertices=rng.integers(0, n, (texels, 3)).astype(np.int64),
        texel_dual=rng.uniform(-0.5, 1.5, (texels, 3)).astype(np.float32),
        texel_direct=rng.uniform(0.0, 0.2, (texels, 3, 3)).astype(np.float32),
        f_indptr=indptr, f_indices=indices, f_values=rng.uniform(1e-5, 0.05, (len(indices), 3)).astype(np.float32),
        border_texels=border, border_vertices=rng.integers(0, surface or n, (borders, 3)).astype(np.int64),
        border_barycentric=rng.dirichlet(np.ones(3), borders).astype(np.float32),
        surface_vertex_count=surface or n,
        surface_global=(np.repeat(np.arange(n)[:, None], 3, axis=1) if surface is None
                        else rng.integers(0, n, (surface, 3))).astype(np.int64),
        surface_weights=(np.tile([1.0, 0.0, 0.0], (n, 1)) if surface is None
                         else rng.dirichlet(np.ones(3), surface)).astype(np.float32),
    )
    data.check()
    return data


def assert_tradeoff_written(result: dict, json_name: str) -> None:
    """A tradeoff's JSON holds `result` under `json_name`, its CSV the rows, its plot something."""
    assert json.loads(Path(result["outputs"]["json"]).read_text()) == result
    assert Path(result["outputs"]["json"]).name == json_name
    with open(result["outputs"]["csv"]) as f:
        saved = list(csv.DictReader(f))
    assert len(saved) == len(result["rows"]) and list(saved[0]) == list(result["rows"][0])
    assert Path(result["outputs"]["plot"]).stat().st_size > 0


def bake_screen_sphere(folder: Path, **overrides):
    """Bake a small generated icosphere (radius 5 units; marble, 1 mm per unit unless `overrides`
    say otherwise) with the screen technique alone.

    Returns the `BakeResult` and the `BakeOptions` it was baked with.
    """
    import trimesh

    from sssbake.pipeline.bake.asset import bake_asset
    from sssbake.pipeline.bake.cache import StageCache
    from sssbake.pipeline.options import BakeOptions

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    trimesh.creation.icosphere(subdivisions=2, radius=5.0).export(folder / "ball.obj")
    options = BakeOptions(**{"material": "marble", "scale_mm": 1.0, "atlas_resolution": 64, "techniques": ("screen",),
                             "validate": False, **overrides})
    return bake_asset(folder / "ball.obj", options, folder / "ball", StageCache(None)), options


# A batch config's defaults that keep a bake cheap: the fallback only (techniques is given, since
# its default is the planner's), small atlases.
FAST_DEFAULTS = """\
[defaults]
material = "marble"
scale_mm = 1.0
techniques = []
atlas_resolution = 64
"""
