"""Regenerates pipeline/core/data/montecarlo_profile.npz, the Monte Carlo diffusion profile table
(`montecarlo_profile.build_table`): random walks at every η node and reference absorption.

    python benchmarks/build_profile_table.py [--photons 500000] [--seed 1] [--walks DIR]

--walks keeps each walk's exits in DIR (``walk_<eta>_<a0>_<photons>_<seed>.npz``) and reuses them,
so a run that stopped picks up where it was. 500k photons per walk took ~25 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import time
from importlib import resources
from pathlib import Path

import numpy as np

from sssbake.pipeline.core.montecarlo_profile import TABLE, build_table
from sssbake.pipeline.core.random_walk import Exits, random_walk


def cached_walk(folder: Path):
    def walk(eta: float, photons: int, absorption: float, max_length: float, seed: int) -> Exits:
        path = folder / f"walk_{eta}_{absorption}_{photons}_{seed}.npz"
        if path.exists():
            with np.load(path) as d:
                return Exits(eta, absorption, photons, d["radius"], d["length"], d["cos_out"], max_length)
        t = time.perf_counter()
        exits = random_walk(eta, photons, absorption, max_length, seed)
        np.savez(path, radius=exits.radius, length=exits.length, cos_out=exits.cos_out)
        print(f"eta {eta} a0 {absorption}: {photons} photons in {time.perf_counter() - t:.1f} s", flush=True)
        return exits
    return walk


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=int, default=500_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--walks", type=Path, help="folder to keep and reuse the walks in")
    parser.add_argument("--out", type=Path, default=Path(str(resources.files("sssbake.pipeline.core").joinpath(TABLE))))
    args = parser.parse_args()
    walk = random_walk
    if args.walks:
        args.walks.mkdir(parents=True, exist_ok=True)
        walk = cached_walk(args.walks)
    table = build_table(args.photons, args.seed, walk)
    np.savez_compressed(args.out, **table)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
