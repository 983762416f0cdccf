"""kernels precompute: F's bytes per vertex bounded (``f_bytes``, default 64) against F unbounded
(``f_bytes 0``: the global response on the surface, or on a 20k-vertex copy of denser ones), and
the error the bound costs.

    python benchmarks/bench_kernels.py [--meshes hand dragon] [--resolution 512] [--f-bytes 64]
        [--accuracy]
    python benchmarks/bench_kernels.py --gl-limits

Per mesh and variant: the global mesh's vertices, F's entries, F's bytes per welded surface vertex,
the kernels tables' bytes as the .glb stores them (8-bit kernels, the bake's default), seconds and
the share of F's light the per-source bound moved. Then the bounded against the unbounded, for four
illuminations of the texels (uniform; a directional light, shadowed; a point light at one
bounding-box diagonal, unshadowed; the half of the mesh facing the light lit, the rest dark):
relative L2 (area-weighted) of the smooth vertex response B_g + B_d at the surface vertices and of
q at the texels (`evaluate.texel_q`). ``--accuracy`` also compares q at the texels of both with the
offline reference for the directional light (exact pair sum; the bake's clustered sum above 20k
vertices). ``--gl-limits``: the GL runtime's passes on synthetic data of 800k global vertices
and a 2048² atlas (`gl_limits`), against numpy.

Meshes from ../shared/assets at the scales of benchmarks/shared_assets.toml (hand 200 mm/unit
skin1, dragon 10 mm/unit skin2, armadillo 150 mm/unit potato). Each mesh runs in a fresh process.
Skips meshes whose files are absent.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.fresnel import fresnel_transmittance
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.core.surface import vertex_areas
from sssbake.pipeline.core.visibility import direction_visibility
from sssbake.pipeline.mesh.atlas import compute_atlas
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.surface_locate import locate_on_mesh
from sssbake.pipeline.techniques.kernels.evaluate import texel_q, vertex_response
from sssbake.pipeline.techniques.kernels.layout import kernels_bytes
from sssbake.pipeline.techniques.kernels.precompute import KERNELS_DEFAULTS, precompute_kernels

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
#: name -> (file, mm per unit, material)
MESHES = {
    "hand": ("hand/hand_closed.obj", 200.0, "skin1"),
    "dragon": ("dragon/dragon.obj", 10.0, "skin2"),
    "armadillo": ("armadillo/armadillo.obj", 150.0, "potato"),
}
LIGHT = (0.4, 0.8, 0.45)
#: Above this many vertices the accuracy reference is the clustered sum (the exact one takes minutes).
EXACT_UP_TO = 20_000


def illuminations(pre, surface, light: np.ndarray, eta: float) -> dict[str, np.ndarray]:
    """name -> E at the covered and border texels (`KernelsData` step 1)."""
    points = np.r_[pre.positions, pre.border_positions]
    normals = np.r_[pre.normals, pre.border_normals]
    cos = np.clip(normals @ light, 0.0, None)
    visible = direction_visibility(surface.positions, surface.faces, surface.normals, light[None], points,
                                   normals)[:, 0]
    lo, hi = surface.positions.min(axis=0), surface.positions.max(axis=0)
    lamp = 0.5 * (lo + hi) + light * np.linalg.norm(hi - lo)
    towards = lamp - points
    r2 = np.einsum("ij,ij->i", towards, towards)
    cos_point = np.clip(np.einsum("ij,ij->i", normals, towards) / np.sqrt(r2), 0.0, None)
    side = points @ light
    return {"uniform": np.ones(len(points)),
            "directional": fresnel_transmittance(eta, cos) * cos * visible / np.pi,
            "point": fresnel_transmittance(eta, cos_point) * cos_point * r2.min() / r2 / np.pi,
            "half": (side > np.median(side)).astype(np.float64)}


def responses(pre, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(surface vertex response B_g + B_d (n_s, 3), q at the texels (S, 3)) for E at the texels."""
    d = pre.data
    flat = np.zeros(d.width * d.height)
    flat[np.r_[d.texels, d.border_texels]] = image
    e = flat.reshape(d.height, d.width)
    _, b_d, b_g = vertex_response(d, e)
    vertex = np.einsum("vk,vkc->vc", d.surface_weights.astype(np.float64), (b_g + b_d)[d.surface_global])
    return vertex, texel_q(d, e, pre.barycentric)


def relative(a: np.ndarray, b: np.ndarray, weight: np.ndarray) -> float:
    """Area-weighted relative L2 of a against b, all channels."""
    return float(np.sqrt((weight[:, None] * (a - b) ** 2).sum() / max((weight[:, None] * b**2).sum(), 1e-300)))


def run(name: str, resolution: int, f_bytes: float, accuracy: bool) -> str:
    file, mm, material_name = MESHES[name]
    clean = clean_scene(load_scene(str(ASSETS / file)))
    mesh, surface = clean.scene.meshes[0], clean.surfaces[0]
    material = preset(material_name)
    n_s = len(surface.positions)
    atlas = compute_atlas([(p.positions, p.faces) for p in mesh.primitives], resolution, 4)
    prims = [(p.positions, p.normals) for p in mesh.primitives]
    light = np.asarray(LIGHT) / np.linalg.norm(LIGHT)
    lines = [f"{name}: {n_s} vertices, {mm:g} mm/unit {material_name}, atlas {atlas.width}x{atlas.height}"]
    variants = {}
    for label, bound in (("unbounded", 0.0), ("bounded", f_bytes)):
        t = time.perf_counter()
        pre = precompute_kernels(surface, atlas, prims, mm, material, replace(KERNELS_DEFAULTS, f_bytes=bound))
        seconds = time.perf_counter() - t
        size, st = kernels_bytes(pre.data, 8), pre.stats
        variants[label] = pre
        lines.append(f"  {label} (f_bytes {bound:g}): global vertices {st['globalVertices']}, F {st['nnz']} entries "
                     f"({st['nnzPerVertex']:.1f} per global vertex, {st['fMoved']:.3f} of its light moved), "
                     f"F {size['f'] / n_s:.1f} B per vertex ({size['f'] / 2**20:.2f} MB); kernels tables "
                     f"{size['total'] / 2**20:.2f} MB ({size['perVertex']:.0f} B per vertex); precompute "
                     f"{seconds:.1f} s (throughput {pre.seconds['throughput']:.1f} s)")
    full, bounded = variants["unbounded"], variants["bounded"]
    area = vertex_areas(surface.positions, surface.faces)
    images = illuminations(full, surface, light, material.eta)
    q_refs = {}
    for pattern, image in images.items():
        (v_full, q_full), (v_b, q_b) = responses(full, image), responses(bounded, image)
        q_refs[pattern] = (q_full, q_b)
        lines.append(f"  {pattern}: bounded vs unbounded F, relative L2: vertex response B_g + B_d "
                     f"{relative(v_b, v_full, area):.4f}, q at the texels {relative(q_b, q_full, full.areas):.4f}; "
                     f"mean q ratio {np.round(q_b.mean(axis=0) / np.maximum(q_full.mean(axis=0), 1e-300), 4).tolist()}")
    if accuracy:
        t = time.perf_counter()
        reference = reference_scattering(surface, mm, material, Light("directional", tuple(light)),
                                         clustered=n_s > EXACT_UP_TO)
        lines.append(f"  reference ({'clustered' if n_s > EXACT_UP_TO else 'exact'}) {time.perf_counter() - t:.1f} s")
        # the reference at the texels' points, through the surface triangle each lies on
        face, bary = locate_on_mesh(full.positions, surface.positions, surface.faces)
        ref = np.einsum("sa,csa->sc", bary, reference[:, surface.faces[face]])
        for label, pre in variants.items():
            q = q_refs["directional"][0 if label == "unbounded" else 1]
            lines.append(f"  {label}: q at the texels vs the reference, directional light: "
                         f"{relative(q, ref, pre.areas):.4f} relative L2, mean ratio "
                         f"{np.round(q.mean(axis=0) / ref.mean(axis=0), 4).tolist()}")
    return "\n".join(lines)


def gl_limits(vertices: int = 800_000, side: int = 2048, covered: int = 1_200_000, per_source: int = 4) -> str:
    """The GL runtime's passes on synthetic data at the largest supported size (`vertices` global
    vertices with `per_source` F entries each, a `side`² atlas with `covered` texels, 7 × 7
    kernels, random values) against numpy: every table must fit GL_MAX_TEXTURE_SIZE."""
    from sssbake.pipeline.render.renderer import Renderer, RenderLight
    from sssbake.pipeline.techniques.kernels.data import KernelsData
    from sssbake.pipeline.techniques.kernels.evaluate import local_response

    rng = np.random.default_rng(1)
    n, k, s = vertices, 7, covered
    rows = np.repeat(np.arange(n), per_source)
    indices = rng.integers(0, n, n * per_source)
    order = np.lexsort((indices, rows))
    rows, indices = rows[order], indices[order]
    distinct = np.r_[True, (indices[1:] != indices[:-1]) | (rows[1:] != rows[:-1])]
    rows, indices = rows[distinct], indices[distinct]
    data = KernelsData(
        width=side, height=side, kernel_size=k, vertex_count=n,
        texels=np.sort(rng.choice(side * side, s, replace=False)).astype(np.int64),
        kernels=rng.normal(0.0, 0.05, (s, k * k, 3)).astype(np.float32), texel_vertices=rng.integers(0, n, (s, 3)),
        texel_dual=rng.uniform(-0.5, 1.5, (s, 3)).astype(np.float32),
        texel_direct=rng.uniform(0.0, 0.2, (s, 3, 3)).astype(np.float32),
        f_indptr=np.r_[0, np.cumsum(np.bincount(rows, minlength=n))].astype(np.int64), f_indices=indices,
        f_values=rng.uniform(1e-5, 0.05, (len(indices), 3)).astype(np.float32),
        border_texels=np.zeros(0, np.int64), border_vertices=np.zeros((0, 3), np.int64),
        border_barycentric=np.zeros((0, 3), np.float32), surface_vertex_count=n,
        surface_global=np.repeat(np.arange(n)[:, None], 3, axis=1),
        surface_weights=np.tile(np.float32([1.0, 0.0, 0.0]), (n, 1)))
    data.check()
    positions = rng.normal(size=(n, 3))
    item = dict(positions=positions, normals=positions, faces=rng.integers(0, n, (20, 3)),
                uvs=rng.uniform(0, 1, (n, 2)), vertex_ids=np.arange(n), model=np.eye(4), eta=1.4, kernels=data)
    e = rng.uniform(0.0, 2.0, (side, side))
    renderer = Renderer((64, 64), shadow_size=64)
    try:
        t = time.perf_counter()
        out = renderer.passes(item, RenderLight(), given=e)
        seconds = time.perf_counter() - t
        limit = renderer.ctx.info["GL_MAX_TEXTURE_SIZE"]
    finally:
        renderer.release()
    e_g, b_d, b_g = vertex_response(data, e)
    errors = {name: float(np.abs(out[name] - cpu).max() / np.abs(cpu).max())
              for name, cpu in (("local", local_response(data, e)), ("e_g", e_g), ("b_d", b_d), ("b_g", b_g))}
    return (f"GL limits: {n} global vertices, {len(indices)} F entries, {s} texels x {k * k} kernel weights, "
            f"GL_MAX_TEXTURE_SIZE {limit}: passes {seconds:.1f} s, largest relative error against numpy "
            f"{max(errors.values()):.1e} ({', '.join(f'{k} {v:.1e}' for k, v in errors.items())})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--meshes", nargs="+", default=["hand", "dragon"], choices=sorted(MESHES))
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--f-bytes", type=float, default=KERNELS_DEFAULTS.f_bytes)
    ap.add_argument("--accuracy", action="store_true", help="also compare q with the offline reference")
    ap.add_argument("--gl-limits", action="store_true", help="only run the runtime on synthetic 800k-vertex data")
    args = ap.parse_args()
    if args.gl_limits:
        print(gl_limits())
        return
    for name in args.meshes:
        if not (ASSETS / MESHES[name][0]).is_file():
            print(f"{name}: skipped, {ASSETS / MESHES[name][0]} not found")
            continue
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            try:
                print(pool.submit(run, name, args.resolution, args.f_bytes, args.accuracy).result(), flush=True)
            except ValueError as e:
                print(f"{name}: {e}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
