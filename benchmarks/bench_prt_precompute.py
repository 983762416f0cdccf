"""prt precompute: seconds and peak memory per step, and convergence across mesh resolutions.

    python benchmarks/bench_prt_precompute.py [--k 200] [--meshes dragon.obj dragon_subdiv1.ply]
        [--vertices N] [--converge-k 16] [--no-converge]

Uses the Stanford dragon files from ../shared/assets/dragon (50k, 200k, 800k vertices, the same
surface; scale 10 mm per unit makes it ~14 cm long), marble. Skips when they are absent.
``--vertices N`` first simplifies each timed mesh to about N vertices (the issue's 150k figure:
``--meshes dragon_subdiv1.ply --vertices 150000``).
"""

from __future__ import annotations

import argparse
import resource
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from sssbake.pipeline.core.directions import direction_set
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.mesh.clean import clean_scene
from sssbake.pipeline.mesh.load import load_scene
from sssbake.pipeline.mesh.scene import Mesh, Primitive, Scene
from sssbake.pipeline.mesh.simplify import simplify
from sssbake.pipeline.techniques.prt.precompute import precompute_prt

DRAGON = Path(__file__).resolve().parents[2] / "shared" / "assets" / "dragon"
SCALE_MM = 10.0


def surface(name: str, vertices: int | None = None):
    scene = load_scene(str(DRAGON / name))
    s = clean_scene(scene).surfaces[0]
    if vertices is None:
        return s
    simple = simplify(s.positions, s.faces, target_count=2 * vertices)
    return clean_scene(with_mesh(scene, simple.positions, simple.faces)).surfaces[0]


def with_mesh(scene: Scene, positions: np.ndarray, faces: np.ndarray) -> Scene:
    """`scene` with its one mesh replaced by a derived triangle list, for `clean_scene` as a bake does."""
    return replace(scene, meshes=(Mesh(scene.meshes[0].name, (Primitive(positions, faces),)),))


def timed_precompute(name: str, vertices: int | None, k: int) -> str:
    """One timed precompute, as a line of figures."""
    s = surface(name, vertices)
    directions = direction_set(k).directions
    t = time.perf_counter()
    res = precompute_prt(s, SCALE_MM, preset("marble"), directions)
    total = time.perf_counter() - t
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    steps = ", ".join(f"{key} {v:.1f} s" for key, v in res.seconds.items())
    return (f"{name}: {len(s.positions)} vertices, K={k}: {total:.1f} s ({steps}); process peak RSS {rss:.0f} MB; "
            f"operator {res.stats['entries'] / len(s.positions):.0f} entries/vertex, "
            f"{res.stats['operator_bytes'] / 2**20:.0f} MB, built at {res.seconds['operator'] / res.stats['entries'] * 1e9:.0f} "
            f"ns/entry; radius {np.round(res.radius_mm, 2)} mm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--k", type=int, default=200)
    ap.add_argument("--meshes", nargs="*", default=["dragon.obj", "dragon_subdiv1.ply"])
    ap.add_argument("--vertices", type=int, default=None, help="simplify each timed mesh to about this many vertices")
    ap.add_argument("--converge-k", type=int, default=16)
    ap.add_argument("--converge", nargs="+", default=["dragon.obj", "dragon_subdiv1.ply", "dragon_subdiv2.ply"])
    ap.add_argument("--no-converge", action="store_true")
    args = ap.parse_args()
    if not DRAGON.is_dir():
        print(f"skipped: {DRAGON} not found")
        return
    material = preset("marble")
    for name in args.meshes:
        # A fresh process per mesh: its peak RSS is this precompute's alone (no tracemalloc,
        # which slows the threaded steps several-fold).
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            print(pool.submit(timed_precompute, name, args.vertices, args.k).result(), flush=True)
    if args.no_converge:
        return
    # The same surface at three resolutions: q at the coarser mesh's vertices (present in the
    # subdivided files) should agree up to discretisation and the gather's error, and agree
    # more closely between finer pairs.
    directions = direction_set(args.converge_k).directions
    meshes = [(args.converge[0], surface(args.converge[0]))]
    fields = [precompute_prt(meshes[0][1], SCALE_MM, material, directions).q]
    for name in args.converge[1:]:
        s = surface(name)
        q = precompute_prt(s, SCALE_MM, material, directions).q
        tree = cKDTree(s.positions)
        for (coarse_name, coarse), q0 in [(meshes[0], fields[0]), (meshes[-1], fields[-1])][:1 + (len(meshes) > 1)]:
            dist, idx = tree.query(coarse.positions)
            err = np.abs(q[:, idx, :] - q0)
            print(f"{coarse_name} vs {name} (K={args.converge_k}, at {len(coarse.positions)} vertices matched within "
                  f"{dist.max() * SCALE_MM:.2g} mm): rms diff / rms q = {np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(q0**2)):.4f}, "
                  f"max diff / max q = {err.max() / q0.max():.4f}, "
                  f"99th pct diff / max q = {np.quantile(err, 0.99) / q0.max():.4f}", flush=True)
        meshes.append((name, s))
        fields.append(q)

if __name__ == "__main__":
    main()
