"""The planner under an error budget: ``sssbake bake --techniques auto --budget-rmse X`` on a folder
(default ../shared/assets with benchmarks/shared_assets.toml), one line per (asset, mesh,
material): the plan, the pilot's pick and the kept one, bytes per vertex, bake seconds (the pilot,
every bake and every check), the full asset's RMSE against the budget, and the bakes it took.

    python benchmarks/bench_plan.py [--path ../shared/assets] [--budget 0.02] [--max-bytes 32]
        [--out DIR] [--report]

RMSE is `sssbake verify`'s image RMSE at 160² under its default light, the reference summed
exactly up to 30k vertices and through clusters above. A second run of the same command reads
the cache and the checked reports and takes seconds.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from sssbake.exporters.inspect_gltf import inspect_glb
from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.config import load_config
from sssbake.pipeline.techniques.footprint import footprint

HERE = Path(__file__).resolve().parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--path", default=str(HERE.parent.parent / "shared" / "assets"))
    parser.add_argument("--config", default=str(HERE / "shared_assets.toml"))
    parser.add_argument("--budget", type=float, default=0.02, help="image RMSE budget")
    parser.add_argument("--max-bytes", type=float, default=32.0, help="most bytes per vertex the planner may spend")
    parser.add_argument("--out", help="output folder (default: a temporary one)")
    parser.add_argument("--report", action="store_true", help="also write OUT/report.html")
    args = parser.parse_args()
    if not Path(args.path).exists():
        print(f"{args.path} absent: nothing to plan")
        return
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_plan_"))
    t = time.perf_counter()
    summary = run_batch([Path(args.path)], out, load_config(args.config),
                        {"techniques": ["auto"], "budget_rmse": args.budget, "max_bytes_per_vertex": args.max_bytes},
                        cache_dir=str(out / ".sssbake-cache"), progress=False)
    print(f"{summary['ok']} baked, {summary['failed']} failed in {time.perf_counter() - t:.0f} s; budget "
          f"{args.budget:g}, at most {args.max_bytes:g} B/vertex; outputs in {out}")
    print(f"{'asset':<22} {'mesh / material':<34} {'pilot pick -> kept':<62} {'B/vert':>6} "
          f"{'s':>5} {'RMSE':>7} {'budget':>9} bakes")
    for record in summary["assets"]:
        name = Path(record["asset"]).name
        if record["status"] == "failed":
            print(f"{name:<28} failed: {record['error']}")
            continue
        report = json.loads(Path(next(p for p in record["outputs"] if p.endswith(".report.json"))).read_text())
        used = footprint(inspect_glb(next(p for p in record["outputs"] if p.endswith(".glb"))))["techniques"]
        check = report.get("check", {})
        kept = check.get("figures", {})
        for e in report["plan"] or [{"mesh": "-", "material": "-", "techniques": []}]:
            technique = e["techniques"][0] if e["techniques"] else None
            pilot = e.get("pilot")
            short = (lambda i: pilot["candidates"][i]["label"].split(" (")[0]) if pilot else None
            picks = technique or "none" if pilot is None else f"{short(pilot['chosen'])} -> {short(pilot['pick'])}"
            figures = kept.get(technique, {}) if technique else {}
            per_vertex = used.get(technique, {}).get("total", 0.0)
            rmse = figures.get("rmse_image")
            verdict = ("unchecked" if "skipped" in figures else "-") if rmse is None else (
                "within" if rmse <= args.budget else "over")
            print(f"{name:<22.22} {e['mesh'] + ' / ' + e['material']:<34.34} {picks:<62.62} {per_vertex:>6.1f} "
                  f"{check.get('seconds', record['seconds']):>5.0f} {'-' if rmse is None else f'{rmse:.4f}':>7} {verdict:>9} "
                  f"{len(check.get('attempts', []))}")
    if args.report:
        from sssbake.pipeline.verify.html_report import write_report

        print(f"report in {write_report(out, summary)}")


if __name__ == "__main__":
    main()
