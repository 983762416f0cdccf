"""The escape gain (`pipeline/mesh/escape_gain.py`) against an independent walk, and its cost.

    python benchmarks/bench_escape_gain.py [--photons 20000] [--meshes duck,hand,armadillo,nefertiti,dragon]

The reference walks a sphere with its exact ray-sphere intersection, and an infinite slab between
two planes (numba, its own random numbers, no embree, no mesh; the half-space walk's Fresnel), so
it shares no geometry code with the product's walk on the icosphere mesh (5 subdivisions) of the
same radius and on a 400 × 400 × 2 mm box; both use the same
physics (diffuse entry, isotropic scattering with the reduced coefficients, exact Fresnel from
inside). Also prints the
product's gain and time on the shared meshes at benchmarks/shared_assets.toml's scales.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numba
import numpy as np
import trimesh

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.random_walk import _reflectance_inside  # the half-space walk's Fresnel (numba)
from sssbake.pipeline.mesh.escape_gain import escape_gain

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "assets"
MESHES = {"duck": (SHARED / "duck" / "Duck.glb", 100.0), "hand": (SHARED / "hand" / "hand_closed.obj", 200.0),
          "armadillo": (SHARED / "armadillo" / "armadillo.obj", 150.0),
          "nefertiti": (SHARED / "nefertiti" / "nefertiti-lowres.obj", 1.0), "dragon": (SHARED / "dragon" / "dragon.obj", 10.0)}


@numba.njit(parallel=True)
def _exact_walk(n, size, sigma_s, sigma_a, eta, shape, seed):
    """Shares of n photons entering a body that leave it, in all and behind the light they entered
    from (the exit's normal facing away from it). `shape` 0: the plane z = 0 over z < 0; 1: a
    sphere of radius `size`; 2: the infinite slab -size < z < 0."""
    out = np.zeros(n)
    behind = np.zeros(n)
    sigma_t = sigma_s + sigma_a
    albedo = sigma_s / sigma_t
    for k in numba.prange(n):
        np.random.seed(seed + k)
        sin_t = np.sqrt(1.0 - np.random.random()) / eta
        cos_t = np.sqrt(1.0 - sin_t * sin_t)
        phi = 2.0 * np.pi * np.random.random()
        dx, dy, dz = sin_t * np.cos(phi), sin_t * np.sin(phi), -cos_t
        sin_e = eta * sin_t  # towards the light: the exterior direction before refraction
        lx, ly, lz = -sin_e * np.cos(phi), -sin_e * np.sin(phi), np.sqrt(1.0 - sin_e * sin_e)
        px, py, pz = 0.0, 0.0, (size * (1.0 - 1e-12) if shape == 1 else -1e-12)
        while True:
            s = -np.log(1.0 - np.random.random()) / sigma_t
            if shape == 1:
                b = px * dx + py * dy + pz * dz
                c = px * px + py * py + pz * pz - size * size
                t = -b + np.sqrt(max(b * b - c, 0.0))
            elif dz > 0:
                t = -pz / dz
            else:
                t = (-size - pz) / dz if shape == 2 and dz < 0 else 1e300
            if s < t:
                px, py, pz = px + s * dx, py + s * dy, pz + s * dz
                if np.random.random() > albedo:
                    break
                z = 2.0 * np.random.random() - 1.0
                r = np.sqrt(1.0 - z * z)
                a = 2.0 * np.pi * np.random.random()
                dx, dy, dz = r * np.cos(a), r * np.sin(a), z
            else:
                px, py, pz = px + t * dx, py + t * dy, pz + t * dz
                if shape == 1:
                    nx, ny, nz = px / size, py / size, pz / size
                else:
                    nx, ny, nz = 0.0, 0.0, (1.0 if dz > 0 else -1.0)
                ci = dx * nx + dy * ny + dz * nz
                if np.random.random() < _reflectance_inside(ci, eta):
                    dx, dy, dz = dx - 2 * ci * nx, dy - 2 * ci * ny, dz - 2 * ci * nz
                    px, py, pz = px - 1e-9 * nx, py - 1e-9 * ny, pz - 1e-9 * nz
                else:
                    out[k] = 1.0
                    behind[k] = 1.0 if nx * lx + ny * ly + nz * lz < 0.0 else 0.0
                    break
    return out.mean(), behind.mean()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=int, default=20000)
    parser.add_argument("--meshes", default="duck,hand,armadillo")
    args = parser.parse_args()
    bodies = [(f"sphere r {r:g} mm", 1, r, trimesh.creation.icosphere(subdivisions=5, radius=r)) for r in (10.0, 100.0)]
    # a slab wide enough that its rim (1 % of the area) hardly counts, against the infinite slab
    bodies.append(("slab 2 mm (mesh 400 x 400 mm)", 2, 2.0, trimesh.creation.box(extents=(400.0, 400.0, 2.0))))
    for label, shape, size, mesh in bodies:
        for name in ("marble", "skin1"):
            m = preset(name)
            walks = [(_exact_walk(args.photons, size, m.sigma_s_prime[c], m.sigma_a[c], m.eta, shape, 11),
                      _exact_walk(args.photons, size, m.sigma_s_prime[c], m.sigma_a[c], m.eta, 0, 11)[0])
                     for c in range(3)]
            reference = [escaped / plane for (escaped, _), plane in walks]
            behind = [back / plane for (_, back), plane in walks]
            t = time.perf_counter()
            product = escape_gain(mesh.vertices, mesh.faces, 1.0, m)
            print(f"{label} {name}: exact walk {np.round(reference, 3).tolist()} "
                  f"(behind {np.round(behind, 3).tolist()}), escape_gain {np.round(product.gain, 3).tolist()} "
                  f"(behind {np.round(product.back, 3).tolist()}; {product.photons} photons, "
                  f"{time.perf_counter() - t:.1f} s)", flush=True)
    for key in args.meshes.split(","):
        path, mm = MESHES[key]
        if not path.is_file():
            print(f"{key}: {path} is missing, skipped")
            continue
        mesh = trimesh.load(path, force="mesh")
        mesh.merge_vertices()  # welded, as the bake's surface is
        for name in ("marble", "skin1"):
            t = time.perf_counter()
            g = escape_gain(mesh.vertices, mesh.faces, mm, preset(name))
            print(f"{key} ({len(mesh.vertices)} vertices, {mm:g} mm/unit) {name}: escape_gain "
                  f"{np.round(g.gain, 3).tolist()} (behind {np.round(g.back, 4).tolist()}) closed {g.closed} "
                  f"({time.perf_counter() - t:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
