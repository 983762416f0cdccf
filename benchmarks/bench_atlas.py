"""The atlas stage on the meshes of ../shared/assets: xatlas on the whole mesh (what every scattering
mesh got before) against `proxy_atlas.layout_atlas` (the input's UVs when they pass, else a proxy's
charts carried back), back to back in one process, and the check's figures.

    python benchmarks/bench_atlas.py [--only duck,dragon] [--resolution 512] [--proxy-min-faces 1]

``--proxy-min-faces 1`` charts a proxy of every mesh without valid UVs: the cutover (`PROXY_MIN_FACES`).
``--fidelity`` bakes the thickness texture on both atlases and prints how far it strays from the
per-vertex thickness at the vertices (bilinear samples; median and 95th percentile over the mesh's
median thickness): what the texture loses to charts, seams and texel size.

Per mesh: triangles, seconds of each way and their ratio, the layout taken and why others were
refused, the texture coverage and doubly covered texels of both. Every mesh of the files is timed,
the truck's opaque glass and wheels too (a bake charts none of them); the helmet, all opaque in
benchmarks/shared_assets.toml, is left out.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sssbake.pipeline.bake.stages import ThicknessParams, thickness_stage
from sssbake.pipeline.mesh.atlas import compute_atlas
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.proxy_atlas import PROXY_MIN_FACES, layout_atlas
from sssbake.pipeline.mesh.thickness_map import bake_thickness_map
from sssbake.pipeline.mesh.uv_check import check_uvs

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
FILES = ["teapot/teapot.obj", "duck/Duck.glb", "hand/hand_closed.obj", "armadillo/armadillo.obj",
         "stanford_bunny/bunny.ply", "nefertiti/nefertiti-lowres.obj", "dragon/dragon.obj",
         "cesium_milk_truck/CesiumMilkTruck.glb"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="comma-separated folder names, e.g. duck,dragon (default: all but the helmet)")
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--padding", type=int, default=4)
    ap.add_argument("--proxy-min-faces", type=int, default=PROXY_MIN_FACES)
    ap.add_argument("--fidelity", action="store_true", help="also the thickness texture against the vertices'")
    args = ap.parse_args()
    if not ASSETS.is_dir():
        print(f"skipped: {ASSETS} not found")
        return
    files = [f for f in FILES if not args.only or f.split("/")[0] in args.only.split(",")]
    total_old = total_new = 0.0
    print(f"{'mesh':<34} {'faces':>7} {'xatlas s':>9} {'new s':>7} {'ratio':>6}  layout (coverage, overlap: old / new)")
    for name in files:
        cleaned = clean_scene(load_scene(ASSETS / name))
        for mesh, surface in zip(cleaned.scene.meshes, cleaned.surfaces):
            parts = [(p.positions, p.faces, p.uvs) for p in mesh.primitives]
            t0 = time.perf_counter()
            old = compute_atlas([(p, f) for p, f, _ in parts], args.resolution, args.padding)
            t1 = time.perf_counter()
            new = layout_atlas(parts, args.resolution, args.padding, proxy_min_faces=args.proxy_min_faces)
            t2 = time.perf_counter()
            total_old += t1 - t0
            total_new += t2 - t1
            checks = [check_uvs([(part.uvs, part.faces, p[part.vmapping]) for part, (p, _, _) in zip(a.parts, parts)],
                                a.width, a.height) for a in (old, new)]
            faces = sum(len(f) for _, f, _ in parts)
            label = f"{Path(name).stem}/{mesh.name}"[:34]
            print(f"{label:<34} {faces:7d} {t1 - t0:9.2f} {t2 - t1:7.2f} {(t2 - t1) / (t1 - t0):6.2f}  {new.source} "
                  f"({checks[0].coverage:.2f}, {checks[0].overlap:.1e} / {checks[1].coverage:.2f}, "
                  f"{checks[1].overlap:.1e}) {'; '.join(new.notes)}", flush=True)
            if args.fidelity:
                print(f"{'':<34} thickness texture at the vertices: xatlas {_fidelity(old, mesh, surface)}, "
                      f"new {_fidelity(new, mesh, surface)}", flush=True)
    print(f"{'all':<34} {'':>7} {total_old:9.2f} {total_new:7.2f} {total_new / max(total_old, 1e-9):6.2f}")


def _fidelity(atlas, mesh, surface) -> str:
    """Median and 95th percentile of |texture - vertex thickness| / median thickness."""
    cap = float(np.linalg.norm(np.ptp(surface.positions, axis=0)))
    normals = [p.normals for p in mesh.primitives]
    thickness = thickness_stage(surface, normals, cap, ThicknessParams(1)).thickness
    image = bake_thickness_map(atlas, [(p.positions, p.normals) for p in mesh.primitives], surface, cap, 1, 4).image
    height, width = image.shape
    errors = []
    for i, part in enumerate(atlas.parts):
        x, y = part.uvs[:, 0] * width - 0.5, part.uvs[:, 1] * height - 0.5
        x0 = np.clip(np.floor(x).astype(int), 0, width - 2)
        y0 = np.clip(np.floor(y).astype(int), 0, height - 2)
        fx, fy = np.clip(x - x0, 0, 1), np.clip(y - y0, 0, 1)
        sampled = (image[y0, x0] * (1 - fx) * (1 - fy) + image[y0, x0 + 1] * fx * (1 - fy)
                   + image[y0 + 1, x0] * (1 - fx) * fy + image[y0 + 1, x0 + 1] * fx * fy)
        errors.append(np.abs(sampled - thickness[surface.weld[i][part.vmapping]]))
    errors, scale = np.concatenate(errors), np.median(thickness)
    return f"{np.median(errors) / scale:.4f} / {np.percentile(errors, 95) / scale:.4f}"


if __name__ == "__main__":
    main()
