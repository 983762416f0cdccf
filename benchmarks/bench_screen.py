"""screen technique (Mertens et al. 2003): image RMSE against the exact offline reference and frame
time in the reference runtime for N importance samples, on meshes from ../shared/assets.

    python benchmarks/bench_screen.py [--meshes hand bunny] [--samples 8,16,32,64] [--size 512]
        [--lights 3] [--frames 20] [--reference-subdivisions 1] [--out DIR]

Meshes at the scales of benchmarks/shared_assets.toml (hand 200 mm/unit skin1, bunny 1000 mm/unit
marble, armadillo 150 mm/unit potato, teapot 25 mm/unit wholemilk, dragon 10 mm/unit skin2).
The figures are `screen_tradeoff`'s rows of the N sweep (U and the runtime options at their
defaults): RMSE the worst over `--lights` random test lights (seeded), over the image and over
the object's pixels, and per light, the reference computed per vertex on the surface subdivided
`--reference-subdivisions` times (the technique shades per pixel); frame time the median of
`--frames` frames under the first light (shadow map, G-buffer, gather, resolve and the final
draw), next to the plain shader's. On a CPU machine the
frame times are Mesa llvmpipe's; on a GPU machine, the GPU's. Skips meshes whose files are absent.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_spectral import ASSETS, MESHES  # noqa: E402

from sssbake.pipeline.core.materials import preset  # noqa: E402
from sssbake.pipeline.techniques.screen.tradeoff import screen_tradeoff  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--meshes", nargs="+", default=["hand", "bunny"],
                        choices=[m for m, (_, _, _, simplified) in MESHES.items() if simplified is None])
    parser.add_argument("--samples", default="8,16,32,64", help="N values, comma-separated")
    parser.add_argument("--size", type=int, default=512, help="image width and height (the paper: 500)")
    parser.add_argument("--lights", type=int, default=3)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--reference-subdivisions", type=int, default=1,
                        help="midpoint subdivisions of the reference's surface (default 1: 4x the faces)")
    parser.add_argument("--out", help="folder for the tradeoff files (default: a temporary one)")
    args = parser.parse_args()
    samples = tuple(int(n) for n in args.samples.split(","))
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_screen_"))
    for name in args.meshes:
        file, mm, material, _ = MESHES[name]
        if not (ASSETS / file).exists():
            print(f"{name}: {ASSETS / file} absent, skipped")
            continue
        result = screen_tradeoff(ASSETS / file, mm, preset(material), out / name, samples=samples, uniform=(),
                                 runtime_changes=(), lights=args.lights, size=args.size, frames=args.frames,
                                 reference_subdivisions=args.reference_subdivisions)
        facing = ", ".join(f"{v:+.2f}" for v in result["lights_towards_camera"])
        print(f"{name}: {result['vertices']} vertices (reference on {result['reference_vertices']}), {mm:g} mm/unit "
              f"{material}, {args.size}x{args.size}, worst of {args.lights} lights (cosine to the camera {facing}); plain shader "
              f"{result['frame_ms_plain']:.2f} ms/frame")
        for r in result["rows"]:
            if r["sweep"] == "samples":
                per_light = ", ".join(f"{v:.5f}" for v in r["rmse_image_per_light"])
                print(f"  N={r['samples']:<4} U={r['uniform']:<3} RMSE image {r['rmse_image']:.5f} "
                      f"object {r['rmse_object']:.5f} (per light {per_light})  {r['frame_ms']:8.2f} ms/frame  "
                      f"tables {r['bytes']} B")
    print(f"files in {out}")


if __name__ == "__main__":
    main()
