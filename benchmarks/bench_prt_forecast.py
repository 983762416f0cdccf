"""prt's forecast against what it forecasts: entries, bytes, build seconds and seconds per
direction from the 2 % sample (`scatter_forecast`), then the gather built and applied.

    python benchmarks/bench_prt_forecast.py [--meshes dragon.obj dragon_subdiv1.ply] [--vertices N]
        [--no-build]

Dragon files from ../shared/assets/dragon, marble, 10 mm per unit, K = 200 (skips when absent).
``--no-build`` prints the forecast alone (the 800k gather needs ~18 GB to build).
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
from bench_prt_precompute import DRAGON, SCALE_MM, surface

from sssbake.pipeline.core.profile import profile_for
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.scatter_operator import scatter_plan
from sssbake.pipeline.techniques.prt.forecast import prt_forecast

K = 200


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--meshes", nargs="+", default=["dragon.obj", "dragon_subdiv1.ply"])
    ap.add_argument("--vertices", type=int, default=None)
    ap.add_argument("--no-build", action="store_true")
    args = ap.parse_args()
    if not DRAGON.is_dir():
        print(f"skipped: {DRAGON} is absent")
        return
    for name in args.meshes:
        s = surface(name, args.vertices)
        x = s.positions * SCALE_MM
        t = time.perf_counter()
        plan = scatter_plan(x, s.faces, s.normals, profile_for(preset("marble")))
        t_plan = time.perf_counter() - t
        t = time.perf_counter()
        f = prt_forecast(plan, K)
        t_forecast = time.perf_counter() - t
        print(f"{name} ({len(x)} vertices): plan {t_plan:.1f} s, forecast {t_forecast:.1f} s: {f.entries / 1e6:.1f}M "
              f"entries, operator {f.gather.operator_bytes / 1e9:.2f} GB, peak {f.peak_bytes / 1e9:.2f} GB, "
              f"build + {K} directions {f.seconds:.1f} s", flush=True)
        if args.no_build:
            continue
        t = time.perf_counter()
        op = plan.build()
        t_build = time.perf_counter() - t
        signal = np.random.default_rng(0).random((len(x), 64))
        t = time.perf_counter()
        op.apply(signal)
        per = (time.perf_counter() - t) / 64
        print(f"  built: {op.nnz / 1e6:.1f}M entries, operator {op.nbytes / 1e9:.2f} GB, build {t_build:.1f} s, "
              f"{per:.4f} s per direction (build + {K}: {t_build + K * per:.1f} s), process peak "
              f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB", flush=True)


if __name__ == "__main__":
    main()
