"""kernels precompute: seconds per step, peak memory, F's size and bytes, and (``--accuracy``) the
error of q at the texels against the exact offline reference for each blending mode.

    python benchmarks/bench_kernels.py [--meshes hand armadillo armadillo10k] [--resolution 512]
        [--threshold 1e-5] [--accuracy]

Meshes from ../shared/assets at the scales of benchmarks/shared_assets.toml (hand 200 mm/unit skin1,
armadillo 150 mm/unit potato); ``armadillo10k`` is the armadillo simplified to 10k vertices (the
issue's 10k figure), ``dragon150k`` the 200k dragon simplified to 150k at 10 mm/unit, marble.
Each mesh runs in a fresh process, so its peak RSS is its own. Skips meshes whose files are absent.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_prt_precompute import with_mesh  # noqa: E402

from sssbake.pipeline.core.fresnel import fresnel_transmittance  # noqa: E402
from sssbake.pipeline.core.materials import preset  # noqa: E402
from sssbake.pipeline.core.reference import Light, reference_scattering  # noqa: E402
from sssbake.pipeline.core.visibility import direction_visibility  # noqa: E402
from sssbake.pipeline.mesh.atlas import compute_atlas  # noqa: E402
from sssbake.pipeline.mesh.clean import clean_scene  # noqa: E402
from sssbake.pipeline.mesh.load import load_scene  # noqa: E402
from sssbake.pipeline.mesh.simplify import simplify  # noqa: E402
from sssbake.pipeline.techniques.kernels.evaluate import texel_q  # noqa: E402
from sssbake.pipeline.techniques.kernels.layout import kernels_bytes  # noqa: E402
from sssbake.pipeline.techniques.kernels.precompute import (  # noqa: E402
    BLENDS,
    KernelsPrecomputeOptions,
    precompute_kernels,
)

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
#: name -> (file, mm per unit, material, vertices to simplify to or None)
MESHES = {
    "hand": ("hand/hand_closed.obj", 200.0, "skin1", None),
    "armadillo": ("armadillo/armadillo.obj", 150.0, "potato", None),
    "armadillo10k": ("armadillo/armadillo.obj", 150.0, "potato", 10_000),
    "dragon150k": ("dragon/dragon_subdiv1.ply", 10.0, "marble", 150_000),
}
LIGHT = (0.4, 0.8, 0.45)


def run(name: str, resolution: int, threshold: float, accuracy: bool) -> str:
    file, mm, material_name, vertices = MESHES[name]
    scene = clean_scene(load_scene(str(ASSETS / file))).scene
    if vertices is not None:
        s = clean_scene(scene).surfaces[0]
        simple = simplify(s.positions, s.faces, target_count=2 * vertices)
        scene = clean_scene(with_mesh(scene, simple.positions, simple.faces)).scene
    clean = clean_scene(scene)
    mesh, surface = clean.scene.meshes[0], clean.surfaces[0]
    material = preset(material_name)
    t = time.perf_counter()
    atlas = compute_atlas([(p.positions, p.faces) for p in mesh.primitives], resolution, 4)
    atlas_seconds = time.perf_counter() - t
    prims = [(p.positions, p.normals) for p in mesh.primitives]
    lines = []
    errors = {}
    light = np.asarray(LIGHT) / np.linalg.norm(LIGHT)
    reference = None
    for blend in BLENDS if accuracy else ("optimised",):
        t = time.perf_counter()
        options = KernelsPrecomputeOptions(threshold=threshold, blend=blend)
        pre = precompute_kernels(surface, atlas, prims, mm, material, options)
        seconds = time.perf_counter() - t
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        if blend == "optimised":
            b16, b8 = kernels_bytes(pre.data, 16), kernels_bytes(pre.data, 8)
            steps = ", ".join(f"{k} {v:.1f}" for k, v in pre.seconds.items())
            st = pre.stats
            lines.append(
                f"{name}: {len(surface.positions)} vertices, {mm:g} mm/unit {material_name}; atlas {atlas.width}x"
                f"{atlas.height} ({atlas_seconds:.1f} s, {atlas.chart_count} charts); precompute {seconds:.1f} s "
                f"({steps}); peak RSS {rss:.0f} MB; texels {st['texels']} + border {st['borderTexels']}; "
                f"F {st['nnz']} non-zeros ({st['nnzPerVertex']:.0f}/vertex, radius {st['throughputRadiusMm']:.1f} mm, "
                f"{b16['f'] / 2**20:.1f} MB); file {b16['total'] / 2**20:.1f} MB with 16-bit kernels "
                f"({b16['kernels'] / 2**20:.1f} MB kernels), {b8['total'] / 2**20:.1f} MB with 8-bit")
        if accuracy:
            if reference is None:
                t = time.perf_counter()
                reference = reference_scattering(surface, mm, material, Light("directional", tuple(light)))
                lines.append(f"  exact reference {time.perf_counter() - t:.1f} s")
            d = pre.data
            points = np.r_[pre.positions, pre.border_positions]
            normals = np.r_[pre.normals, pre.border_normals]
            visible = direction_visibility(surface.positions, surface.faces, surface.normals, light[None], points,
                                           normals)[:, 0]
            cos = np.clip(normals @ light, 0.0, None)
            image = np.zeros(d.width * d.height)
            image[np.r_[d.texels, d.border_texels]] = fresnel_transmittance(material.eta, cos) * cos * visible / np.pi
            q = texel_q(d, image.reshape(d.height, d.width), pre.barycentric)
            ref = np.einsum("sa,csa->sc", pre.barycentric, reference[:, d.texel_vertices])
            errors[blend] = np.sqrt(np.mean((q - ref) ** 2) / np.mean(ref**2))
            lines.append(f"  {blend}: q at the texels vs the reference interpolated there: {errors[blend]:.4f} "
                         f"relative rms, mean ratio {np.round(q.mean(axis=0) / ref.mean(axis=0), 4).tolist()}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--meshes", nargs="+", default=["hand", "armadillo", "armadillo10k"], choices=sorted(MESHES))
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--threshold", type=float, default=1e-5)
    ap.add_argument("--accuracy", action="store_true", help="also compare each blending mode with the exact reference")
    args = ap.parse_args()
    for name in args.meshes:
        if not (ASSETS / MESHES[name][0]).is_file():
            print(f"{name}: skipped, {ASSETS / MESHES[name][0]} not found")
            continue
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            try:
                print(pool.submit(run, name, args.resolution, args.threshold, args.accuracy).result(), flush=True)
            except ValueError as e:
                print(f"{name}: {e}", flush=True)


if __name__ == "__main__":
    main()
