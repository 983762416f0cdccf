"""prt precompute: seconds and peak memory per step, and convergence across mesh resolutions.

    python benchmarks/bench_prt_precompute.py [--k 200] [--meshes dragon.obj dragon_subdiv1.ply]
        [--converge-k 16] [--no-converge]

Uses the Stanford dragon files from ../shared/assets/dragon (50k, 200k, 800k vertices, the same
surface; scale 10 mm per unit makes it ~14 cm long), marble. Skips when they are absent.
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.clean import clean_scene
from sssbake.pipeline.directions import direction_set
from sssbake.pipeline.load import load_scene
from sssbake.pipeline.materials import preset
from sssbake.pipeline.prt_precompute import precompute_prt

DRAGON = Path(__file__).resolve().parents[2] / "shared" / "assets" / "dragon"
SCALE_MM = 10.0


def surface(name: str):
    return clean_scene(load_scene(str(DRAGON / name))).surfaces[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--k", type=int, default=200)
    ap.add_argument("--meshes", nargs="*", default=["dragon.obj", "dragon_subdiv1.ply"])
    ap.add_argument("--converge-k", type=int, default=16)
    ap.add_argument("--converge", nargs="+", default=["dragon.obj", "dragon_subdiv1.ply", "dragon_subdiv2.ply"])
    ap.add_argument("--no-converge", action="store_true")
    args = ap.parse_args()
    if not DRAGON.is_dir():
        print(f"skipped: {DRAGON} not found")
        return
    material = preset("marble")
    for name in args.meshes:
        s = surface(name)
        directions = direction_set(args.k).directions
        tracemalloc.start()
        t = time.perf_counter()
        res = precompute_prt(s, SCALE_MM, material, directions)
        total = time.perf_counter() - t
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        steps = ", ".join(f"{k} {v:.1f} s" for k, v in res.seconds.items())
        print(f"{name}: {len(s.positions)} vertices, K={args.k}: {total:.1f} s ({steps}); traced peak "
              f"{peak:.0f} MB, process peak RSS {rss:.0f} MB; operator {res.stats['entries'] / len(s.positions):.0f} "
              f"entries/vertex, {res.stats['operator_bytes'] / 2**20:.0f} MB; radius {np.round(res.radius_mm, 2)} mm")
        del res
    if args.no_converge:
        return
    # The same surface at three resolutions: q at the coarse mesh's vertices (present in the
    # subdivided files) should agree up to discretisation and the gather's error.
    directions = direction_set(args.converge_k).directions
    base = surface(args.converge[0])
    q0 = precompute_prt(base, SCALE_MM, material, directions).q
    for name in args.converge[1:]:
        s = surface(name)
        q = precompute_prt(s, SCALE_MM, material, directions).q
        dist, idx = cKDTree(s.positions).query(base.positions)
        q = q[:, idx, :]
        err = np.abs(q - q0)
        print(f"{args.converge[0]} vs {name} (K={args.converge_k}, matched within {dist.max() * SCALE_MM:.2g} mm): "
              f"rms diff / rms q = {np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(q0**2)):.4f}, "
              f"max diff / max q = {err.max() / q0.max():.4f}, "
              f"99th pct diff / max q = {np.quantile(err, 0.99) / q0.max():.4f}")


if __name__ == "__main__":
    main()
