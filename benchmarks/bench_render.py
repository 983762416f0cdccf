"""Reference runtime frame times: prt decoding per vertex vs a plain Lambert/specular shader vs
per-vertex radiance (``vertex_q``), at several image sizes.

    python benchmarks/bench_render.py [--mesh PATH] [--sizes 512 1024] [--frames 10] [--k 200]
        [--order 3] [--reference-fraction 0.01] [--dialect glsl330] [--tables shared|rgb]
        [--weight-bits 8|16]

The mesh defaults to ../shared/assets/dragon/dragon_subdiv1.ply (200k vertices), else an
icosphere of 164k vertices. The prt data is random but valid (random codes and weights, K
directions, reference triangles over a `reference-fraction` of the vertices): decoding cost does
not depend on the values. Each figure is the median of `frames` frames, each ended by
``ctx.finish()``; on Mesa llvmpipe the times are CPU times.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.render.renderer import Renderer, RenderLight, fit_camera
from sssbake.pipeline.techniques.prt.data import PrtData

DRAGON = Path(__file__).resolve().parents[2] / "shared" / "assets" / "dragon" / "dragon_subdiv1.ply"
LIGHT = (0.4, 0.8, 0.45)


def mesh(path: Path | None) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """Name, positions (n, 3), normals (n, 3), faces (m, 3)."""
    path = path or (DRAGON if DRAGON.is_file() else None)
    if path is None:
        import trimesh

        s = trimesh.creation.icosphere(subdivisions=7)
        return "icosphere(7)", np.asarray(s.vertices), np.asarray(s.vertices), np.asarray(s.faces)
    from sssbake.pipeline.mesh.clean import clean_scene
    from sssbake.pipeline.mesh.load import load_scene

    s = clean_scene(load_scene(str(path))).surfaces[0]
    return path.name, s.positions, s.normals, s.faces


def random_prt(n: int, k: int, order: int, fraction: float, rng: np.random.Generator, channels: int = 1,
               weight_bits: int = 8) -> PrtData:
    """Valid `PrtData` over n vertices with random codes; ~2 reference triangles per reference point;
    `channels` 1 (shared tables) or 3 (RGB); 8-bit weights only where the triangles fit their
    16-bit index, as compression chooses."""
    ds = direction_set(k)
    refs = max(3, int(fraction * n))
    triangles = 2 * refs
    c = order * order
    return PrtData(
        directions=ds.directions.astype(np.float32), direction_triangles=ds.triangles.astype(np.int32),
        direction_inverse=ds.inverse.astype(np.float32), direction_lookup=ds.lookup.astype(np.int32),
        direction_neighbours=ds.neighbours.astype(np.int32),
        lut=np.sort(rng.uniform(0.0, 1.0, (3, 256)), axis=1).astype(np.float32),
        ref_vertices=rng.choice(n, refs, replace=False).astype(np.int64),
        ref_codes=rng.integers(0, 256, (refs, k, channels), dtype=np.uint8),
        ref_scale=rng.uniform(0.5, 1.0, (refs if channels == 1 else 0, 3)).astype(np.float32),
        ref_triangles=rng.integers(0, refs, (triangles, 3), dtype=np.int32),
        # neighbouring vertices share reference triangles, as after simplification
        vertex_triangle=(np.arange(n) * triangles // n).astype(np.int32),
        weight_codes=rng.integers(0, 64, (n, 2), dtype=np.int16), weight_scale=1.0,
        weight_bits=weight_bits if triangles <= 65536 else 16,
        dq_codes=rng.integers(-127, 128, (n, 3, c), dtype=np.int8),
        dq_scale=np.full((3, c), 0.01, np.float32), sh_order=order, eta=1.3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", type=Path)
    ap.add_argument("--sizes", type=int, nargs="+", default=[512, 1024])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--k", type=int, default=200)
    ap.add_argument("--order", type=int, default=3)
    ap.add_argument("--reference-fraction", type=float, default=0.01)
    ap.add_argument("--dialect", default="glsl330")
    ap.add_argument("--tables", choices=["shared", "rgb"], default="shared")
    ap.add_argument("--weight-bits", type=int, choices=[8, 16], default=8)
    args = ap.parse_args()
    name, positions, normals, faces = mesh(args.mesh)
    rng = np.random.default_rng(0)
    prt = random_prt(len(positions), args.k, args.order, args.reference_fraction, rng,
                     1 if args.tables == "shared" else 3, args.weight_bits)
    base = dict(positions=positions, normals=normals, faces=faces, model=np.eye(4), eta=1.3)
    items = {"prt": {**base, "prt": prt}, "plain": {**base, "albedo": (0.8, 0.8, 0.8)},
             "vertex_q": {**base, "q": rng.uniform(0.0, 1.0, (len(positions), 3))}}
    camera = fit_camera(positions)
    light = RenderLight(False, LIGHT, 1.0)
    print(f"{name}: {len(positions)} vertices, {len(faces)} triangles; prt K={args.k}, SH order {args.order}, "
          f"{len(prt.ref_codes)} reference points, {args.tables} tables, {prt.weight_bits}-bit weights; "
          f"{args.dialect}")
    for size in args.sizes:
        renderer = Renderer((size, size), args.dialect)
        ms = {kind: renderer.frame_ms([item], camera, light, args.frames) for kind, item in items.items()}
        renderer.release()
        print(f"  {size}x{size}: prt {ms['prt']:.1f} ms, plain {ms['plain']:.1f} ms, vertex_q {ms['vertex_q']:.1f} ms; "
              f"prt/plain {ms['prt'] / ms['plain']:.2f}x")


if __name__ == "__main__":
    main()
