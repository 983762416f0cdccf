"""prt compression: bytes per vertex against image and q error, on real q (marble).

    python benchmarks/bench_prt_compress.py [--meshes bunny dragon] [--configs old default ...]
        [--k 200] [--lights 6] [--size 256] [--seed 0]

Settings by name (`CONFIGS`): ``old`` (the defaults before shared tables, refinement and 8-bit
weights), ``default``, ``paper`` (3 % reference points, SH order 3, barycentric weights), one
change from ``old`` at a time at about its bytes (``shared``, ``refine``, ``w8``), the reference
fraction around the default and above it, ``budget20`` (a 20 B/vertex byte budget), ``detail4``
and ``detail4-budget20`` (a detail term of SH order 4 per reference point), and ``floor`` /
``floor-rgb`` (every vertex a reference point: what the table coding alone costs in error).

q comes from `precompute_prt` for the Stanford bunny (../shared/assets/stanford_bunny/bunny.ply,
1000 mm per unit) and dragon (../shared/assets/dragon/dragon.obj, 10 mm per unit; ``dragon200k``,
the same surface at 200k vertices, on request; ``teapot200k``, the Utah teapot after three Loop
subdivisions at 30 mm per unit, near the paper's 150k-vertex teapot) and is cached in /tmp as .npy (a rerun only compresses). For each compression setting it prints bytes per vertex
(`bytes_per_vertex`, every byte), the rms q error at the direction set relative to the largest q,
and image RMSE against the interpolated uncompressed q (as ``sssbake tradeoff`` measures it, the
worst of `lights` random directional lights): over the whole image (the paper's figure) and over
the object's pixels. Skips meshes whose files are absent.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh
from bench_prt_precompute import with_mesh  # this folder is on the path when run as a script

from sssbake.pipeline.core.directions import direction_set, interpolation_weights
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.render.renderer import Renderer, fit_camera
from sssbake.pipeline.render.sweep import image_exposure, lit_images, worst_rmse
from sssbake.pipeline.techniques.prt.compress import PRT_COMPRESS_DEFAULTS, PrtCompressOptions, compress_prt
from sssbake.pipeline.techniques.prt.decode import bytes_per_vertex, decode_at_directions, evaluate
from sssbake.pipeline.techniques.prt.precompute import precompute_prt

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
#: name -> (file, mm per unit, Loop subdivisions before the precompute).
MESHES = {"bunny": ("stanford_bunny/bunny.ply", 1000.0, 0), "dragon": ("dragon/dragon.obj", 10.0, 0),
          "dragon200k": ("dragon/dragon_subdiv1.ply", 10.0, 0), "teapot200k": ("teapot/teapot.obj", 30.0, 3)}
#: The settings compared: name -> options (the defaults of the previous session as "old").
CONFIGS = {
    "old": PrtCompressOptions(reference_fraction=0.015, sh_order=0, weights="best_fit", tables="rgb", refine=0.0,
                              weight_bits=16),
    "default": PRT_COMPRESS_DEFAULTS,
    "paper": PrtCompressOptions(reference_fraction=0.03, sh_order=3, weights="barycentric", tables="rgb",
                                refine=0.0, weight_bits=16),
    # one change at a time from "old", then together
    "shared": PrtCompressOptions(reference_fraction=0.04, tables="shared", refine=0.0, weight_bits=16),
    "refine": PrtCompressOptions(reference_fraction=0.015, tables="rgb", refine=0.6, weight_bits=16),
    "w8": PrtCompressOptions(reference_fraction=0.022, tables="rgb", refine=0.0, weight_bits=8),
    "shared+refine": PrtCompressOptions(reference_fraction=0.05, refine=0.6, weight_bits=16),
    **{f"default{p}%": replace(PRT_COMPRESS_DEFAULTS, reference_fraction=p / 100) for p in (6, 6.5, 7, 7.5, 15, 30)},
    "budget20": replace(PRT_COMPRESS_DEFAULTS, byte_budget=20.0),
    # a detail term per reference point at about the default's bytes (for dense meshes)
    "detail4": replace(PRT_COMPRESS_DEFAULTS, detail_order=4, reference_fraction=0.06),
    "detail4-budget20": replace(PRT_COMPRESS_DEFAULTS, detail_order=4, byte_budget=20.0),
    # every vertex a reference point: the floor of the table coding alone
    "floor": replace(PRT_COMPRESS_DEFAULTS, reference_fraction=1.0, refine=0.0),
    "floor-rgb": replace(PRT_COMPRESS_DEFAULTS, reference_fraction=1.0, refine=0.0, tables="rgb"),
}


def load_q(name: str, k: int):
    """(surface, q (3, n, K)) with q cached in /tmp."""
    path, mm, subdivisions = MESHES[name]
    scene = load_scene(str(ASSETS / path))
    surface = clean_scene(scene).surfaces[0]
    if subdivisions:
        x, f = trimesh.remesh.subdivide_loop(surface.positions, surface.faces, iterations=subdivisions)
        surface = clean_scene(with_mesh(scene, x, f)).surfaces[0]
    ds = direction_set(k)
    cache = Path(f"/tmp/sssbake_bench_q_{name}_{len(surface.positions)}_{k}.npy")
    if cache.is_file():
        q = np.load(cache)
    else:
        t = time.perf_counter()
        q = precompute_prt(surface, mm, preset("marble"), ds.directions).q
        np.save(cache, q)
        print(f"  precomputed q in {time.perf_counter() - t:.1f} s -> {cache}")
    return surface, ds, q


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", nargs="+", default=["bunny", "dragon"], choices=list(MESHES))
    ap.add_argument("--configs", nargs="+", default=["old", "default"], choices=list(CONFIGS))
    ap.add_argument("--k", type=int, default=200)
    ap.add_argument("--lights", type=int, default=6)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    eta = preset("marble").eta
    renderer = Renderer((args.size, args.size))
    for name in args.meshes:
        if not (ASSETS / MESHES[name][0]).is_file():
            print(f"{name}: skipped, {ASSETS / MESHES[name][0]} not found")
            continue
        surface, ds, q = load_q(name, args.k)
        rng = np.random.default_rng(args.seed)
        lights = rng.normal(size=(args.lights, 3))
        lights /= np.linalg.norm(lights, axis=1, keepdims=True)
        index, beta = interpolation_weights(ds, lights)
        base = dict(positions=surface.positions, normals=surface.normals, faces=surface.faces, model=np.eye(4),
                    eta=eta)
        camera = fit_camera(surface.positions)
        target = lit_images(renderer, camera, base, lights,
                            [np.einsum("cna,a->cn", q[:, :, index[j]], beta[j]) for j in range(args.lights)])
        exposure = image_exposure([image for image, _ in target])
        print(f"{name}: {len(surface.positions)} vertices, K={args.k}, marble, worst of {args.lights} lights, "
              f"{args.size}² images")
        print(f"  {'config':<10} {'B/vertex':>8} {'RMSE image':>10} {'RMSE object':>11} {'q rms/max':>9} "
              f"{'refs':>6} {'seconds':>7}")
        for config in args.configs:
            options = CONFIGS[config]
            t = time.perf_counter()
            prt = compress_prt(q, ds, surface.positions, surface.faces, eta, options)
            seconds = time.perf_counter() - t
            views = lit_images(renderer, camera, base, lights, [evaluate(prt, lights[j]) for j in range(args.lights)])
            images = [image for image, _ in views]
            whole = worst_rmse(images, [image for image, _ in target], exposure)
            masks = [mask | target_mask for (_, mask), (_, target_mask) in zip(views, target)]
            inside = worst_rmse(images, [image for image, _ in target], exposure, masks)
            q_error = float(np.sqrt(np.mean((decode_at_directions(prt) - q) ** 2)) / q.max())
            print(f"  {config:<10} {bytes_per_vertex(prt)['total']:8.2f} {whole:10.2e} {inside:11.2e} "
                  f"{q_error:9.2e} {len(prt.ref_codes):6d} {seconds:7.1f}")
    renderer.release()


if __name__ == "__main__":
    main()
