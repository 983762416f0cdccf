"""What ``sssbake bake … --report`` adds to a bake: the report's verification against the bake's own
time, per asset of ../shared/assets (config benchmarks/shared_assets.toml).

    python benchmarks/bench_report.py [--only armadillo,hand] [--techniques auto] [--old]

Each asset is baked once into a fresh folder without the stage cache (the bake's own seconds), then
`html_report.write_report` verifies what it baked: the clustered reference at every vertex, checked
against the exact sum at a sample of vertices (`checked_reference`). With ``--old`` the same
techniques are also verified as the report did before (`check.check_technique`: the exact sum at
every vertex under 30k vertices, clustered above), in the same process, so the two compare; the
old way takes about three times the bake on the armadillo.
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path

from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.bake.check import check_technique
from sssbake.pipeline.config import load_config
from sssbake.pipeline.techniques.registry import NAMES
from sssbake.pipeline.verify.html_report import write_report

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
CONFIG = Path(__file__).resolve().parent / "shared_assets.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="armadillo,hand", help="comma-separated folders or files of ../shared/assets "
                                                             "(default armadillo,hand)")
    ap.add_argument("--techniques", default="auto", help="as for sssbake bake (default auto)")
    ap.add_argument("--old", action="store_true", help="also verify as the report did before (slow)")
    args = ap.parse_args()
    if not ASSETS.is_dir():
        print(f"skipped: {ASSETS} not found")
        return
    logging.disable(logging.WARNING)
    config = load_config(CONFIG)
    for name in args.only.split(","):
        path = ASSETS / name.strip()
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp)
            summary = run_batch([path], out, config, {"techniques": args.techniques}, cache_dir=None, progress=False)
            t = time.perf_counter()
            write_report(out, summary)
            page_seconds = time.perf_counter() - t
            for record in summary["assets"]:
                if record["status"] != "ok":
                    print(f"{name}: {record['status']} {record.get('error', '')}")
                    continue
                report = json.loads(Path(next(p for p in record["outputs"] if p.endswith(".report.json"))).read_text())
                cost = report.get("verification")
                if cost is None:
                    print(f"{Path(record['asset']).name}: {report['vertices']} vertices, bake "
                          f"{report['seconds']:.1f} s, no technique to verify")
                    continue
                print(f"{Path(record['asset']).name}: {report['vertices']} vertices, bake {report['seconds']:.1f} s; "
                      f"report {page_seconds:.1f} s, verification {cost['seconds']:.1f} s = "
                      f"{cost['bake_fraction']:.2f} x the bake")
                shown = []  # the asset's techniques share a reference: its check is printed once
                for technique, c in cost["techniques"].items():
                    check = c["reference_check"]
                    if not check or check in shown:
                        print(f"  {technique}: {c['seconds']:.1f} s ({c['reference']} reference"
                              f"{', the one above' if check else ''})")
                        continue
                    shown.append(check)
                    lo, hi = check["rms_ci95"]
                    print(f"  {technique}: {c['seconds']:.1f} s (reference {c['reference_seconds']:.1f} s, of it the "
                          f"exact check at {check['vertices']} of {check['of']} vertices and {check['sources']} "
                          f"sources {check['seconds']:.1f} s: RMSE figures within {check['rms']:.2g} [{lo:.2g}, "
                          f"{hi:.2g}] of the exact reference's)")
                if args.old:
                    glb = next(Path(p) for p in record["outputs"] if p.endswith(".glb"))
                    for technique in NAMES:
                        if not report.get(technique):
                            continue
                        t = time.perf_counter()
                        old = check_technique(glb, technique, report["vertices"], out / ".old")
                        seconds = time.perf_counter() - t
                        print(f"  {technique} before ({old.get('reference')} reference): {seconds:.1f} s = "
                              f"{seconds / report['seconds']:.2f} x the bake; rmse_object "
                              f"{old.get('rmse_object', 0):.4f} (now "
                              f"{cost['techniques'][technique].get('rmse_object', float('nan')):.4f})")


if __name__ == "__main__":
    main()
