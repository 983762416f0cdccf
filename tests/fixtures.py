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


def auto_smooth(positions: np.ndarray, faces: np.ndarray, degrees: float = 30.0) -> tuple[np.ndarray, np.ndarray,
                                                                                         np.ndarray]:
    """Render vertices as an exporter's auto-smooth writes them: every triangle corner its own vertex
    (positions (3m, 3), faces (m, 3)), its normal (3m, 3) the corner-angle-weighted mean of the normals
    of the corner vertex's triangles within `degrees` of the corner's own triangle: split across
    harder edges."""
    positions, faces = np.asarray(positions, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    corners = positions[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    unit = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    to_next, to_prev = np.roll(corners, -1, axis=1) - corners, np.roll(corners, 1, axis=1) - corners
    angle = np.arccos(np.clip(np.einsum("fcj,fcj->fc", to_next, to_prev) / (
        np.linalg.norm(to_next, axis=2) * np.linalg.norm(to_prev, axis=2)), -1.0, 1.0))
    order = np.argsort(faces.reshape(-1), kind="stable")  # corners grouped by vertex
    start = np.searchsorted(faces.reshape(-1)[order], np.arange(len(positions) + 1))
    normals = []
    for f, corner in enumerate(faces):
        for v in corner:
            around, at = np.divmod(order[start[v]:start[v + 1]], 3)
            near = unit[around] @ unit[f] > np.cos(np.radians(degrees))
            normals.append((angle[around, at][near, None] * unit[around][near]).sum(axis=0))
    normals = np.array(normals)
    return (corners.reshape(-1, 3), np.arange(3 * len(faces), dtype=np.int64).reshape(-1, 3),
            normals / np.linalg.norm(normals, axis=1, keepdims=True))


def cylinder(radius: float, height: float, segments: int = 32, rings: int = 5,
             caps: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A cylinder about z, from -height/2 to height/2, outward wound: `rings` rings of `segments`
    vertices on its side (positions, faces); with `caps`, each cap a fan about a centre vertex
    (the last two vertices: bottom, top)."""
    angle = 2.0 * np.pi * np.arange(segments) / segments
    z = np.repeat(np.linspace(-0.5 * height, 0.5 * height, rings), segments)
    positions = np.column_stack([radius * np.tile(np.cos(angle), rings), radius * np.tile(np.sin(angle), rings), z])
    ring = np.arange(rings - 1)[:, None] * segments
    a = (ring + np.arange(segments)).ravel()
    b = (ring + (np.arange(segments) + 1) % segments).ravel()
    faces = [np.column_stack([a, b, b + segments]), np.column_stack([a, b + segments, a + segments])]
    if caps:
        j, k = np.arange(segments), (np.arange(segments) + 1) % segments
        bottom, top, last = len(positions), len(positions) + 1, (rings - 1) * segments
        positions = np.vstack([positions, [[0.0, 0.0, -0.5 * height], [0.0, 0.0, 0.5 * height]]])
        faces += [np.column_stack([np.full(segments, bottom), k, j]),
                  np.column_stack([np.full(segments, top), last + j, last + k])]
    return positions, np.concatenate(faces).astype(np.int64)


def hemisphere(radius: float, segments: int = 48, rings: int = 12, base: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The dome z >= 0 of a sphere about the origin, outward wound (positions, faces): a pole vertex
    first, then `rings` rings of `segments` vertices down to the rim in z = 0; with `base`, closed by
    a fan about a last vertex at the origin."""
    polar = np.repeat(0.5 * np.pi * np.arange(1, rings + 1) / rings, segments)
    angle = np.tile(2.0 * np.pi * np.arange(segments) / segments, rings)
    ring_points = radius * np.column_stack([np.sin(polar) * np.cos(angle), np.sin(polar) * np.sin(angle),
                                            np.cos(polar)])
    ring_points[-segments:, 2] = 0.0  # cos(π/2) is 6e-17, not 0: the rim lies in z = 0 exactly
    positions = np.vstack([[[0.0, 0.0, radius]], ring_points])
    j, k = np.arange(segments), (np.arange(segments) + 1) % segments
    faces = [np.column_stack([np.zeros(segments, dtype=np.int64), 1 + j, 1 + k])]
    for i in range(rings - 1):
        a, b = 1 + i * segments + j, 1 + i * segments + k
        faces += [np.column_stack([a, a + segments, b + segments]), np.column_stack([a, b + segments, b])]
    if base:
        rim = 1 + (rings - 1) * segments
        faces.append(np.column_stack([np.full(segments, len(positions)), rim + k, rim + j]))
        positions = np.vstack([positions, [[0.0, 0.0, 0.0]]])
    return positions, np.concatenate(faces).astype(np.int64)


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


def baked_material(result):
    """The scattering material a bake's techniques used (its report's, with the mesh's escape gain),
    for a `BakeResult` of one scattering material."""
    from sssbake.pipeline.core.materials import Material

    (record,) = [m["scattering"] for m in result.report["materials"].values() if m["scattering"]]
    return Material.from_json(record)


# A batch config's defaults that keep a bake cheap: the fallback only (techniques is given, since
# its default is the planner's), small atlases.
FAST_DEFAULTS = """\
[defaults]
material = "marble"
scale_mm = 1.0
techniques = []
atlas_resolution = 64
"""
