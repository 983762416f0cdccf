"""Per-stage bake time and peak memory for one asset (default: the Stanford dragon from ../shared).

    python benchmarks/bench_bake.py [ASSET] [--scale-mm X] [--resolution N] [--techniques prt]

Prints one line per stage: seconds, peak traced allocation of the stage (numpy and Python), and the
process's resident high-water mark after it. Runs without the cache so every stage does its work.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from sssbake.pipeline.bake.asset import bake_asset
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.options import BAKE_DEFAULTS

DEFAULT_ASSET = Path(__file__).resolve().parents[2] / "shared" / "assets" / "dragon" / "dragon.obj"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("asset", nargs="?", default=str(DEFAULT_ASSET))
    ap.add_argument("--scale-mm", type=float, default=10.0, help="mm per file unit (dragon: 10 → 14 cm long)")
    ap.add_argument("--resolution", type=int, default=BAKE_DEFAULTS.atlas_resolution)
    ap.add_argument("--techniques", default="", help="e.g. prt")
    args = ap.parse_args()
    asset = Path(args.asset)
    if not asset.exists():
        print(f"skipped: {asset} not found")
        return
    options = BAKE_DEFAULTS.merged({"scale_mm": args.scale_mm, "atlas_resolution": args.resolution,
                                    "techniques": args.techniques})
    with tempfile.TemporaryDirectory() as tmp:
        result = bake_asset(asset, options, Path(tmp) / asset.stem, StageCache(None), trace_memory=True)
        sizes = {p.suffix: p.stat().st_size for p in result.outputs}
    r = result.report
    print(f"{asset.name}: {r['vertices']} vertices, {r['faces']} faces, total {r['seconds']:.2f} s")
    print(f"{'stage':<14}{'seconds':>9}{'peak traced MB':>16}{'process peak RSS MB':>21}")
    for name, s in r["stages"].items():
        if s.get("skipped"):
            print(f"{name:<14}{'skipped':>9}  ({s['skipped']})")
            continue
        print(f"{name:<14}{s['seconds']:>9.2f}{s.get('peak_traced_mb', 0.0):>16.1f}{s['peak_rss_mb']:>21.1f}")
    for mesh, a in r["atlas"].items():
        print(f"atlas {mesh!r}: {a['width']}x{a['height']} texels, {a['charts']} charts, "
              f"xatlas child peak RSS {a['xatlas_peak_rss_mb']} MB")
    for mesh, p in r["prt"].items():
        print(f"prt {mesh!r}: {json.dumps(p['seconds'])}; {p['referencePoints']} reference points, "
              f"{p['bytesPerVertex']['total']:.1f} B/vertex; q compression rms/max {p['compressionRmsOverMax']:.4f}")
    print("output bytes:", json.dumps(sizes))
    print("validation:", json.dumps(r["validation"]))


if __name__ == "__main__":
    main()
