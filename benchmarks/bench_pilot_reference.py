"""The pilot's offline reference (`planning/pilot.py`): the exact pair sum against the clustered
one on the pilot's subsample of each shared mesh, time and difference.

    python benchmarks/bench_pilot_reference.py [--meshes teapot,hand,armadillo,bunny,dragon]

Each mesh at benchmarks/shared_assets.toml's scale and material, welded, simplified as the pilot
does (`pilot_surface`, `PILOT_VERTICES`), lit by verify's light. Prints seconds of each sum (the
compiled loops warmed first) and the clustered sum's relative L2 and largest difference from the
exact one.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.reference import Light, reference_scattering
from sssbake.pipeline.core.surface import Surface, area_weighted_normals, vertex_areas
from sssbake.pipeline.planning.pilot import PILOT_VERTICES, pilot_surface
from sssbake.pipeline.render.renderer import DEFAULT_LIGHT

SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "assets"
# path, mm per unit, material: as benchmarks/shared_assets.toml
MESHES = {"teapot": (SHARED / "teapot" / "teapot.obj", 25.0, "wholemilk"),
          "hand": (SHARED / "hand" / "hand_closed.obj", 200.0, "skin1"),
          "armadillo": (SHARED / "armadillo" / "armadillo.obj", 150.0, "potato"),
          "bunny": (SHARED / "stanford_bunny" / "bunny.ply", 1000.0, "marble"),
          "dragon": (SHARED / "dragon" / "dragon.obj", 10.0, "skin2")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", default=",".join(MESHES))
    args = parser.parse_args()
    light = Light("directional", tuple(np.asarray(DEFAULT_LIGHT) / np.linalg.norm(DEFAULT_LIGHT)))
    for key in args.meshes.split(","):
        path, mm, name = MESHES[key]
        if not path.is_file():
            print(f"{key}: {path} is missing, skipped")
            continue
        mesh = trimesh.load(path, force="mesh")
        mesh.merge_vertices()  # welded, as the bake's surface is
        x, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
        surface = Surface(positions=x, faces=f, normals=area_weighted_normals(x, f), vertex_areas=vertex_areas(x, f),
                          weld=(np.arange(len(x)),))
        small = pilot_surface(surface, PILOT_VERTICES)
        material = preset(name)
        reference_scattering(small, mm, material, light, clustered=True)  # numba's cache loaded, disc table built
        t = time.perf_counter()
        exact = reference_scattering(small, mm, material, light)
        t_exact = time.perf_counter() - t
        t = time.perf_counter()
        clustered = reference_scattering(small, mm, material, light, clustered=True)
        t_clustered = time.perf_counter() - t
        diff = clustered - exact
        print(f"{key} ({len(small.positions)} of {len(x)} vertices, {name}, {mm:g} mm/unit): exact {t_exact:.2f} s, "
              f"clustered {t_clustered:.2f} s ({t_exact / t_clustered:.1f}x); relative L2 "
              f"{np.linalg.norm(diff) / np.linalg.norm(exact):.2e}, largest {np.abs(diff).max() / np.abs(exact).max():.2e} "
              f"of the largest q", flush=True)


if __name__ == "__main__":
    main()
