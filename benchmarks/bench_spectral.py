"""spectral precompute (Patro 2007): seconds per step and peak memory of the eigensolve, how it
scales with the vertex count, and (``--accuracy``) image RMSE of plain Lambert vs naive vs
spectral normals against the exact offline reference, with the frame-time ratio.

    python benchmarks/bench_spectral.py [--meshes bunny dragon dragon200k] [--eigenpairs 300]
        [--accuracy] [--accuracy-meshes hand armadillo bunny] [--lights 3] [--out DIR]

Meshes from ../shared/assets at the scales of benchmarks/shared_assets.toml (bunny 1000 mm/unit
marble, dragon 10 mm/unit skin2, hand 200 mm/unit skin1, armadillo 150 mm/unit potato, teapot
25 mm/unit wholemilk: open, four components);
``dragon100k`` is the 200k dragon (``dragon_subdiv1.ply``) simplified to 100k vertices. Each mesh
runs in a fresh process, so its peak RSS is its own. Skips meshes whose files are absent. After
the timings, the eigensolve's growth between consecutive sizes of one surface (t ∝ n^p) is
printed with what it predicts for the 800k dragon.

The accuracy figures are `spectral_tradeoff`'s with no sweeps: its plain, default and naive
(α = 0.5) rows, each image times its per-channel best-fit scale (one fit over the lights), the
RMSE the worst over `--lights` random test lights (seeded).
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_prt_precompute import with_mesh  # noqa: E402

from sssbake.pipeline.core.materials import preset  # noqa: E402
from sssbake.pipeline.mesh.clean import clean_scene  # noqa: E402
from sssbake.pipeline.mesh.load import load_scene  # noqa: E402
from sssbake.pipeline.mesh.simplify import simplify  # noqa: E402
from sssbake.pipeline.techniques.spectral.precompute import SpectralPrecomputeOptions, precompute_spectral  # noqa: E402
from sssbake.pipeline.techniques.spectral.tradeoff import spectral_tradeoff  # noqa: E402

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
#: name -> (file, mm per unit, material, vertices to simplify to or None)
MESHES = {
    "hand": ("hand/hand_closed.obj", 200.0, "skin1", None),
    "armadillo": ("armadillo/armadillo.obj", 150.0, "potato", None),
    "bunny": ("stanford_bunny/bunny.ply", 1000.0, "marble", None),
    "teapot": ("teapot/teapot.obj", 25.0, "wholemilk", None),
    "dragon": ("dragon/dragon.obj", 10.0, "skin2", None),
    "dragon100k": ("dragon/dragon_subdiv1.ply", 10.0, "skin2", 100_000),
    "dragon200k": ("dragon/dragon_subdiv1.ply", 10.0, "skin2", None),
}
#: Vertices of the largest dragon file (dragon_subdiv2.ply), for the extrapolation.
LARGEST = 800_000


def timed(name: str, eigenpairs: int) -> tuple[str, int, float]:
    """One timed precompute: a line of figures, the vertex count and the eigensolve's seconds."""
    file, mm, material_name, vertices = MESHES[name]
    scene = load_scene(str(ASSETS / file))
    if vertices is not None:
        s = clean_scene(scene).surfaces[0]
        simple = simplify(s.positions, s.faces, target_count=2 * vertices)
        scene = with_mesh(scene, simple.positions, simple.faces)
    surface = clean_scene(scene).surfaces[0]
    t = time.perf_counter()
    pre = precompute_spectral(surface, mm, preset(material_name), SpectralPrecomputeOptions(eigenpairs=eigenpairs))
    total = time.perf_counter() - t
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    steps = ", ".join(f"{k} {v:.1f} s" for k, v in pre.seconds.items())
    st = pre.stats
    line = (f"{name}: {st['vertices']} vertices, {mm:g} mm/unit {material_name}, m={st['eigenpairs']} in "
            f"{st['bands']} bands: {total:.1f} s ({steps}); process peak RSS {rss:.0f} MB (basis "
            f"{pre.spectrum.basis.nbytes / 2**20:.0f} MB); width {st['widthMm']:.2f} mm, gamma {st['gamma']:.3g}, "
            f"filter at the cut {st['filterAtCutoff']:.3g}; "
            f"mean tilt {st['meanTiltDegrees']:.2f} deg")
    return line, st["vertices"], pre.seconds["eigensolve"]


def accuracy(name: str, lights: int, out: str) -> str:
    """Plain, naive and spectral image RMSE (and fits) on one mesh, and the frame-time ratio."""
    file, mm, material_name, _ = MESHES[name]
    t = time.perf_counter()
    result = spectral_tradeoff(ASSETS / file, mm, preset(material_name), out, eigenpairs=(), width_factors=(),
                               alphas=(0.5,), lights=lights)
    seconds = time.perf_counter() - t
    lines = [f"{name}: {result['vertices']} vertices, {mm:g} mm/unit {material_name}, {lights} lights "
             f"({seconds:.0f} s with the reference)"]
    for r in result["rows"]:
        lines.append(f"  {r['normals']:>8}: image RMSE {r['rmse_image']:.5f} (worst light), best-fit scale "
                     f"{np.round(r['scale'], 4).tolist()}")
    lines.append(f"  frame {result['frame_ms_sss']:.3f} ms with spectral normals, {result['frame_ms_plain']:.3f} ms "
                 f"with the file's: ratio {result['frame_ratio']:.3f}")
    return "\n".join(lines)


def fresh(function, *args):
    """`function(*args)` in a fresh process (its peak RSS its own); None with a line when it fails."""
    with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
        try:
            return pool.submit(function, *args).result()
        except ValueError as e:
            print(f"{args[0]}: {e}", flush=True)
            return None


def present(name: str) -> bool:
    if not (ASSETS / MESHES[name][0]).is_file():
        print(f"{name}: skipped, {ASSETS / MESHES[name][0]} not found", flush=True)
        return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--meshes", nargs="*", default=["bunny", "dragon", "dragon200k"], choices=sorted(MESHES))
    ap.add_argument("--eigenpairs", type=int, default=300)
    ap.add_argument("--accuracy", action="store_true", help="also image RMSE of plain vs naive vs spectral")
    ap.add_argument("--accuracy-meshes", nargs="+", default=["hand", "armadillo", "bunny"], choices=sorted(MESHES))
    ap.add_argument("--lights", type=int, default=3)
    ap.add_argument("--out", help="folder for the accuracy runs' JSON, CSV and plots (default: a temporary one)")
    args = ap.parse_args()
    sizes = {}  # asset folder (one surface at several resolutions) -> [(vertices, eigensolve seconds)]
    for name in args.meshes:
        if present(name) and (done := fresh(timed, name, args.eigenpairs)) is not None:
            print(done[0], flush=True)
            sizes.setdefault(Path(MESHES[name][0]).parent, []).append(done[1:])
    for (n0, t0), (n1, t1) in (pair for family in sizes.values() for pair in zip(sorted(family), sorted(family)[1:])):
        if n1 > n0 and t0 > 0 and t1 > 0:
            p = np.log(t1 / t0) / np.log(n1 / n0)
            print(f"eigensolve {n0} -> {n1} vertices: t ∝ n^{p:.2f}; predicts {t1 * (LARGEST / n1) ** p:.0f} s "
                  f"at {LARGEST} vertices")
    if not args.accuracy:
        return
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.accuracy_meshes:
            if present(name) and (done := fresh(accuracy, name, args.lights, args.out or tmp)) is not None:
                print(done, flush=True)


if __name__ == "__main__":
    main()
