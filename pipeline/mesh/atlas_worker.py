"""Child-process entry point for `sssbake.pipeline.mesh.atlas`: runs xatlas, whose crashes (SIGSEGV on
very regular meshes) must not take the batch down with them.

Usage: ``python -m sssbake.pipeline.mesh.atlas_worker IN.npz OUT.npz ATTEMPT PARENT_PID``.

``IN.npz`` holds ``resolution``, ``padding``, ``n_parts`` and per part ``positions_<i>`` (float32)
and ``faces_<i>`` (uint32). ``OUT.npz`` gets ``width``, ``height``, ``chart_count``, ``peak_rss_mb``
and per part ``vmapping_<i>``, ``faces_<i>``, ``uvs_<i>``.

The environment variable ``SSSBAKE_ATLAS_TEST_CRASHES=k`` makes attempts ``0 .. k-1`` die by
SIGSEGV before xatlas runs, so the parent's retry and error paths can be tested deterministically.
"""

from __future__ import annotations

import os
import signal
import sys

import numpy as np
import xatlas

from sssbake.pipeline.mesh.parent_death import die_with_parent

CRASH_ENV = "SSSBAKE_ATLAS_TEST_CRASHES"


def _peak_rss_mb() -> float:
    """This process's resident high-water mark. VmHWM belongs to the address space made at exec, so
    unlike ru_maxrss it does not count the parent's pages the child held before exec."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")  # no procfs: unknown, reported as null


def main(argv: list[str]) -> None:
    in_path, out_path, attempt, parent = argv[0], argv[1], int(argv[2]), int(argv[3])
    die_with_parent(parent)
    if attempt < int(os.environ.get(CRASH_ENV, "0")):
        os.kill(os.getpid(), signal.SIGSEGV)

    with np.load(in_path) as data:
        n_parts = int(data["n_parts"])
        atlas = xatlas.Atlas()
        for i in range(n_parts):
            atlas.add_mesh(data[f"positions_{i}"], data[f"faces_{i}"])
        pack = xatlas.PackOptions()
        pack.resolution = int(data["resolution"])
        pack.padding = int(data["padding"])
    atlas.generate(xatlas.ChartOptions(), pack)

    out = {
        "width": np.int64(atlas.width),
        "height": np.int64(atlas.height),
        "chart_count": np.int64(atlas.chart_count),
        "peak_rss_mb": np.float64(_peak_rss_mb()),
    }
    for i in range(n_parts):
        vmapping, faces, uvs = atlas[i]
        out[f"vmapping_{i}"] = vmapping
        out[f"faces_{i}"] = faces
        out[f"uvs_{i}"] = uvs
    np.savez(out_path, **out)


if __name__ == "__main__":
    main(sys.argv[1:])
