"""Batch wall time: the local pool with --jobs 1 and --jobs 2, and a 2-worker Dask LocalCluster, on
the meshes in ../shared/assets (config benchmarks/shared_assets.toml).

    python benchmarks/bench_batch.py [--only teapot,duck,hand,armadillo,dragon/dragon.obj] [--techniques none]

Every run bakes into a fresh folder without the stage cache, so each does all the work. The Dask
figure is ``--dask local:2`` as a user runs it, the cluster's start included (also printed apart).
The .glb and .usdc files of every run are compared with --jobs 1's.

--techniques defaults to none (the fallback only: load, clean, atlas, thickness, export, validate),
which measures the batch machinery on every asset in a few minutes; ``--techniques auto`` is the
whole bake (the whole folder then takes a quarter of an hour per run here).
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

from sssbake.pipeline.bake.batch import run_batch
from sssbake.pipeline.config import load_config

ASSETS = Path(__file__).resolve().parents[2] / "shared" / "assets"
CONFIG = Path(__file__).resolve().parent / "shared_assets.toml"


def _inputs(only: str | None) -> list[Path]:
    """The folders or files of ../shared/assets named in `only` (comma-separated: ``teapot``,
    ``dragon/dragon.obj``), or the whole folder."""
    if not only:
        return [ASSETS]
    paths = []
    for name in only.split(","):
        path = ASSETS / name.strip()
        if not path.exists():
            names = sorted(p.name for p in ASSETS.iterdir() if p.is_dir())
            raise SystemExit(f"error: --only {name.strip()}: not in {ASSETS} (folders there: {', '.join(names)})")
        paths.append(path)
    return paths


def _outputs(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.suffix in (".glb", ".usdc")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="comma-separated folders or files of ../shared/assets, e.g. "
                                   "teapot,dragon/dragon.obj (default: all)")
    ap.add_argument("--techniques", default="none", help="as for sssbake bake (default none)")
    ap.add_argument("--workers", type=int, default=2, help="pool processes and Dask workers (default 2)")
    args = ap.parse_args()
    if not ASSETS.is_dir():
        print(f"skipped: {ASSETS} not found")
        return
    paths = _inputs(args.only)
    config = load_config(CONFIG)
    overrides = {"techniques": args.techniques}
    n = args.workers
    from distributed import LocalCluster

    with tempfile.TemporaryDirectory() as tmp:
        rows = []

        def timed(label: str, **kw) -> None:
            out = Path(tmp) / label.replace(" ", "_").replace(":", "")
            t0 = time.perf_counter()
            summary = run_batch(paths, out, config, overrides, cache_dir=None, progress=False, **kw)
            seconds = time.perf_counter() - t0
            rows.append((label, seconds, summary, _outputs(out)))
            per = ", ".join(f"{Path(r['asset']).stem} {r['seconds']:.1f}" for r in summary["assets"])
            print(f"{label:<28} {seconds:7.1f} s  ({summary['ok']} ok, {summary['failed']} failed; "
                  f"per asset s: {per})", flush=True)

        timed("--jobs 1", jobs=1)
        timed(f"--jobs {n}", jobs=n)
        timed(f"--dask local:{n}", dask=f"local:{n}")
        # what of that is the cluster's start (worker processes up, before they import sssbake)
        t0 = time.perf_counter()
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None, silence_logs=logging.ERROR, memory_limit=0):
            started = time.perf_counter() - t0
        print(f"{'(LocalCluster start, close)':<28} {started:7.1f} s, {time.perf_counter() - t0 - started:.1f} s")

        _, base_s, _, base_out = rows[0]
        for label, seconds, summary, outputs in rows[1:]:
            same = "identical" if outputs == base_out else "DIFFERENT"
            print(f"{label:<28} {base_s / seconds:5.2f}x --jobs 1; outputs {same} ({len(outputs)} files)")


if __name__ == "__main__":
    main()
