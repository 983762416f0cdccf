"""Issue 31's choice of a diffusion profile, measured: each candidate against random walks of
their own seed (independent of the walks behind the shipped table), for the 12 measured materials'
albedos at several η.

    python benchmarks/bench_profile.py [--photons 300000] [--etas 1.0,1.25,1.3,1.5]

Per candidate and η: the worst relative error of the total reflectance, and of the light in the
19 annuli that each hold 5 % of the walk's exits (out to its 95 % radius), over the albedos. The
candidates: the classical dipole (Jensen 2001, ``--profile dipole``), the better dipole (d'Eon
2012), photon beam diffusion (Habel 2013), Christensen-Burley 2015 (shape only: its total is the
walk's) and the shipped Monte Carlo profile (``--profile montecarlo``, the default).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from profile_candidates import beam_diffusion, better_dipole, burley  # noqa: E402

from sssbake.pipeline.core.materials import preset, preset_names  # noqa: E402
from sssbake.pipeline.core.montecarlo_profile import PHOTON_FACTORS, REFERENCES, band_energies  # noqa: E402
from sssbake.pipeline.core.profile import disc_integral, profile_of, profile_total, total_reflectance  # noqa: E402
from sssbake.pipeline.core.random_walk import exit_weights, random_walk  # noqa: E402

GRID = np.geomspace(1e-7, 1e7, 6000)  # radii (1/σ'_t) the tabulated candidates are integrated on


def cumulative(values: np.ndarray) -> np.ndarray:
    """2π ∫_0^r R s ds on `GRID` (trapezoids in ln r; a constant R below the first node)."""
    f = 2.0 * np.pi * GRID**2 * values
    steps = 0.5 * (f[1:] + f[:-1]) * np.diff(np.log(GRID))
    first = np.pi * GRID[0] ** 2 * values[0]
    return first + np.r_[0.0, np.cumsum(steps)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=int, default=300_000)
    parser.add_argument("--etas", default="1.0,1.25,1.3,1.5")
    parser.add_argument("--seed", type=int, default=4242)
    args = parser.parse_args()
    albedos = sorted({round(float(x), 12) for n in preset_names() for x in preset(n).albedo_prime})
    names = ("dipole", "better dipole", "beam diffusion", "Christensen-Burley", "montecarlo")
    print(f"{'eta':>4} {'candidate':<19} {'worst total':>11} {'worst annulus':>13}  (over {len(albedos)} albedos)")
    print("     annulus: each of the 19 holding 5 % of the walk's exits, out to its 95 % radius")
    for eta in (float(e) for e in args.etas.split(",")):
        t = time.perf_counter()
        runs = [random_walk(eta, args.photons * f, a0, 1e6, args.seed + 31 * k)
                for k, (a0, f) in enumerate(zip(REFERENCES, PHOTON_FACTORS))]
        worst = {n: [0.0, 0.0, 0.0, 0.0] for n in names}  # total, annulus, its albedo, the walk's noise there
        for alpha in albedos:
            a = (1.0 - alpha) / alpha
            run = runs[int(np.searchsorted(REFERENCES, a, side="right")) - 1]
            weight, radius = exit_weights(run, a), run.radius * (1.0 + a)
            want = float(weight.sum()) if a > 0 else 1.0
            _, edges = band_energies(radius, weight, np.arange(1, 20) * 0.05 * want / float(weight.sum()))
            shipped = profile_of((alpha,) * 3, (1.0 - alpha,) * 3, eta, "montecarlo")
            dipole = profile_of((alpha,) * 3, (1.0 - alpha,) * 3, eta, "dipole")
            curves = {"better dipole": cumulative(better_dipole(GRID, alpha, eta)),
                      "beam diffusion": cumulative(beam_diffusion(GRID, alpha, eta)),
                      "Christensen-Burley": cumulative(burley(GRID, want))}
            for name in names:
                if name in curves:
                    c = curves[name]
                    total, inside = c[-1], np.interp(edges, GRID, c)
                else:
                    p = shipped if name == "montecarlo" else dipole
                    total = float(total_reflectance(p)[0])
                    inside = disc_integral(edges, p)[:, 0] / profile_total(p)[0] * total
                bands = np.abs(np.diff(np.r_[0.0, inside]) / (0.05 * want) - 1.0)
                worst[name][0] = max(worst[name][0], abs(total / want - 1.0))
                if bands.max() > worst[name][1]:
                    which = np.searchsorted(edges, radius)
                    noise = np.sqrt(np.bincount(which, weights=weight * weight, minlength=20)[:19]) / (0.05 * want)
                    worst[name][1:] = float(bands.max()), alpha, float(noise[bands.argmax()])
        for name in names:
            total, band, alpha, noise = worst[name]
            print(f"{eta:4.2f} {name:<19} {total:11.3f} {band:13.3f}  (α' {alpha:.4f}; walk's own noise there {noise:.3f})")
        print(f"     (walks: {time.perf_counter() - t:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
