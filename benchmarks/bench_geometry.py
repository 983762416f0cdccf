"""Time the geometry building blocks on the Stanford dragon (100k faces).

Usage: ``python benchmarks/bench_geometry.py [path/to/mesh.obj]``. Prints wall seconds per step and
this process's peak resident memory so far (ru_maxrss only grows, so a step's peak is the value
printed after it when it is the largest so far). xatlas runs in a child process, not counted here:
a child's ru_maxrss includes the parent pages it had between fork and exec, so it says nothing. Skips when the asset is absent.
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

from sssbake.pipeline.mesh.atlas import compute_atlas
from sssbake.pipeline.mesh.simplify import simplify
from sssbake.pipeline.mesh.texels import rasterize_atlas
from sssbake.pipeline.mesh.thickness import bake_thickness

DEFAULT_ASSET = Path("/work/shared/assets/dragon/dragon.obj")


def _report(step: str, seconds: float, detail: str) -> None:
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{step:<22} {seconds:8.3f} s   peak RSS {peak_mib:8.1f} MiB   {detail}", flush=True)


def main(argv: list[str]) -> int:
    path = Path(argv[0]) if argv else DEFAULT_ASSET
    if not path.is_file():
        print(f"bench_geometry: {path} not found; skipping")
        return 0
    mesh = trimesh.load(path, process=False, force="mesh")
    positions = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    diagonal = float(np.linalg.norm(np.ptp(positions, axis=0)))
    print(f"{path.name}: {len(positions)} vertices, {len(faces)} faces, diagonal {diagonal:.3f}")

    start = time.perf_counter()
    simplified = simplify(positions, faces, 0.1)
    _report("simplify 10 %", time.perf_counter() - start,
            f"{len(simplified.positions)} vertices, {len(simplified.faces)} faces")

    start = time.perf_counter()
    atlas = compute_atlas([(positions, faces)], resolution=512, padding=4)
    _report("atlas (res 512)", time.perf_counter() - start,
            f"{atlas.width} x {atlas.height}, {atlas.chart_count} charts, jittered={atlas.jittered}")

    part = atlas.parts[0]
    start = time.perf_counter()
    texels = rasterize_atlas(
        [(part.uvs, part.faces, positions[part.vmapping], normals[part.vmapping])], atlas.width, atlas.height
    )
    _report("rasterize", time.perf_counter() - start,
            f"{len(texels.rows)} texels of {atlas.width * atlas.height}, area {texels.areas.sum():.4f} "
            f"vs mesh {mesh.area:.4f}")

    cap = 0.25 * diagonal
    start = time.perf_counter()
    per_vertex = bake_thickness(positions, faces, normals, cap=cap)
    seconds = time.perf_counter() - start
    _report("thickness per vertex", seconds,
            f"{len(positions) / seconds / 1e6:.2f} M rays/s, hit {per_vertex.hit.mean():.3f}")

    start = time.perf_counter()
    per_texel = bake_thickness(positions, faces, origins=texels.positions, directions=-texels.normals, cap=cap)
    seconds = time.perf_counter() - start
    _report("thickness per texel", seconds,
            f"{len(texels.rows) / seconds / 1e6:.2f} M rays/s, hit {per_texel.hit.mean():.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
