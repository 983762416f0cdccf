"""The escape gain (`pipeline/mesh/escape_gain.py`) against an independent walk, and its cost.

    python benchmarks/bench_escape_gain.py [--photons 20000] [--meshes duck,hand,armadillo]

The reference walks a sphere with its exact ray-sphere intersection (numba, its own random
numbers, no embree, no mesh; the half-space walk's Fresnel), so it shares no geometry code with
the product's walk on the icosphere mesh (5 subdivisions) of the same radius; both use the same
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
          "armadillo": (SHARED / "armadillo" / "armadillo.obj", 150.0)}


@numba.njit(parallel=True)
def _sphere_walk(n, radius, sigma_s, sigma_a, eta, sphere, seed):
    """Share of n photons entering a sphere (or the plane z = 0 over z < 0) that leave it."""
    out = np.zeros(n)
    sigma_t = sigma_s + sigma_a
    albedo = sigma_s / sigma_t
    for k in numba.prange(n):
        np.random.seed(seed + k)
        sin_t = np.sqrt(1.0 - np.random.random()) / eta
        cos_t = np.sqrt(1.0 - sin_t * sin_t)
        phi = 2.0 * np.pi * np.random.random()
        dx, dy, dz = sin_t * np.cos(phi), sin_t * np.sin(phi), -cos_t
        px, py, pz = 0.0, 0.0, (radius * (1.0 - 1e-12) if sphere else -1e-12)
        while True:
            s = -np.log(1.0 - np.random.random()) / sigma_t
            if sphere:
                b = px * dx + py * dy + pz * dz
                c = px * px + py * py + pz * pz - radius * radius
                t = -b + np.sqrt(max(b * b - c, 0.0))
            else:
                t = -pz / dz if dz > 0 else 1e300
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
                nx, ny, nz = (px / radius, py / radius, pz / radius) if sphere else (0.0, 0.0, 1.0)
                ci = dx * nx + dy * ny + dz * nz
                if np.random.random() < _reflectance_inside(ci, eta):
                    dx, dy, dz = dx - 2 * ci * nx, dy - 2 * ci * ny, dz - 2 * ci * nz
                    px, py, pz = px - 1e-9 * nx, py - 1e-9 * ny, pz - 1e-9 * nz
                else:
                    out[k] = 1.0
                    break
    return out.mean()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=int, default=20000)
    parser.add_argument("--meshes", default="duck,hand,armadillo")
    args = parser.parse_args()
    for radius in (10.0, 100.0):
        sphere = trimesh.creation.icosphere(subdivisions=5, radius=radius)
        for name in ("marble", "skin1"):
            m = preset(name)
            reference = [_sphere_walk(args.photons, radius, m.sigma_s_prime[c], m.sigma_a[c], m.eta, True, 11)
                         / _sphere_walk(args.photons, radius, m.sigma_s_prime[c], m.sigma_a[c], m.eta, False, 11)
                         for c in range(3)]
            t = time.perf_counter()
            product = escape_gain(sphere.vertices, sphere.faces, 1.0, m)
            print(f"sphere r {radius:g} mm {name}: exact-sphere walk {np.round(reference, 3).tolist()}, "
                  f"escape_gain {np.round(product.gain, 3).tolist()} ({product.photons} photons, "
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
                  f"{np.round(g.gain, 3).tolist()} closed {g.closed} ({time.perf_counter() - t:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
