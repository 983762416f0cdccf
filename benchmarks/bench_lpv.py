"""lpv technique (Børlum et al. 2011): image RMSE and frame time in the reference runtime for grid
resolutions × propagation steps, on the dragon (homogeneous, against the exact dipole reference)
and on a veined marble sample (against its own finest configuration: the dipole knows no veins).

    python benchmarks/bench_lpv.py [--cases dragon marble] [--resolutions 16,32,64] [--steps 8,16,32]
        [--size 256] [--lights 3] [--frames 5] [--out DIR]

Cases: ``dragon`` is ../shared/assets/dragon/dragon.obj at 10 mm/unit in skin2 (as
benchmarks/shared_assets.toml), skipped when absent; ``marble`` is the bundled samples' blob
(samples/generate.py, ≈ 30 mm at 1 mm/unit) in marble with veins every 8 mm, as
samples/sssbake.toml bakes it; ``dragon-marble`` is the dragon in homogeneous marble (against the
dipole), a medium 3-7× more translucent than skin2, where the step count matters.
The figures are `lpv_tradeoff`'s rows: RMSE the worst over `--lights` random test lights (seeded),
over the image and the object's pixels; frame time the median of `--frames` frames under the first
light (reflective shadow map, injection, propagation and accumulation, final draw), next to the
plain shader's. On a CPU machine the frame times are Mesa llvmpipe's; on a GPU machine, the GPU's.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "samples"))
from generate import blob  # noqa: E402

from sssbake.pipeline.core.materials import preset  # noqa: E402
from sssbake.pipeline.techniques.lpv.marble_field import MarbleOptions  # noqa: E402
from sssbake.pipeline.techniques.lpv.tradeoff import lpv_tradeoff  # noqa: E402

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
DRAGON = ASSETS / "dragon" / "dragon.obj"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", nargs="+", default=["dragon", "marble"], choices=["dragon", "marble", "dragon-marble"])
    parser.add_argument("--resolutions", default="16,32,64")
    parser.add_argument("--steps", default="8,16,32")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--lights", type=int, default=3)
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--out", help="folder for the tradeoff files (default: a temporary one)")
    args = parser.parse_args()
    resolutions = tuple(int(v) for v in args.resolutions.split(","))
    steps = tuple(int(v) for v in args.steps.split(","))
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_lpv_"))
    for case in args.cases:
        if case.startswith("dragon") and not DRAGON.exists():
            print(f"{case}: {DRAGON} absent, skipped")
            continue
        if case == "marble":
            path = out / "blob.obj"
            blob().export(path)
            mm, material, field, veins = 1.0, "marble", "marble", MarbleOptions(vein_mm=8.0)
        else:
            path, mm = DRAGON, 10.0
            material, field, veins = ("skin2" if case == "dragon" else "marble"), "homogeneous", MarbleOptions()
        result = lpv_tradeoff(path, mm, preset(material), out / case, resolutions=resolutions, steps=steps,
                              field=field, marble=veins, lights=args.lights, size=args.size, frames=args.frames)
        print(f"{case}: {result['vertices']} vertices, {mm:g} mm/unit {material} ({field}), against "
              f"{result['reference']}, {args.size}x{args.size}, worst of {args.lights} lights; plain shader "
              f"{result['frame_ms_plain']:.2f} ms/frame")
        for r in result["rows"]:
            per_light = ", ".join(f"{v:.4f}" for v in r["rmse_image_per_light"])
            print(f"  {r['resolution']:>3}³ ({'x'.join(map(str, r['shape']))}, cell {r['cell_mm']:.2f} mm) "
                  f"{r['steps']:>3} steps: RMSE image {r['rmse_image']:.4f} object {r['rmse_object']:.4f} "
                  f"(per light {per_light})  {r['frame_ms']:9.2f} ms/frame  {r['bytes'] / 1e6:.2f} MB  "
                  f"bake {r['seconds']:.2f} s")
    print(f"files in {out}")


if __name__ == "__main__":
    main()
