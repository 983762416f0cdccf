"""Batch driver: finds assets under the given paths, bakes each (in parallel with --jobs), keeps
going past bad assets, and writes ``OUT/batch.json``.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import os
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from ..exporters.atomic import atomic_path
from .bake import bake_asset
from .plan_check import bake_within_budget
from .cache import StageCache
from .config import BatchConfig, ConfigError
from .load import SUPPORTED_EXTENSIONS, AssetError
from .materials import MaterialError


@dataclass(frozen=True)
class Job:
    """One asset to bake: its path, its path relative to the input root, and where outputs go."""

    path: Path
    rel: str
    out_base: Path


def find_assets(paths: list[Path], out_dir: Path) -> list[Job]:
    """Every supported file under `paths` (folders walked recursively), mirrored under `out_dir`.

    Files inside `out_dir` and hidden folders are skipped. Two inputs that would share an output
    name (``a.obj`` and ``a.ply``) keep their extension in it (``a.obj.glb``).
    """
    out_dir = out_dir.resolve()
    found: list[tuple[Path, Path]] = []
    for root in paths:
        root = Path(root)
        if root.is_file():
            found.append((root, Path(root.name)))
            continue
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: no such file or folder")
        for p in sorted(_walk(root)):
            rel = p.relative_to(root)
            if (
                p.is_file()
                and p.suffix.lower() in SUPPORTED_EXTENSIONS
                and not any(part.startswith(".") for part in rel.parts)
                and out_dir not in p.resolve().parents
            ):
                found.append((p, rel))
    stems: dict[Path, int] = {}
    for _, rel in found:
        stems[rel.with_suffix("")] = stems.get(rel.with_suffix(""), 0) + 1
    jobs = []
    for p, rel in found:
        base = rel.with_suffix("") if stems[rel.with_suffix("")] == 1 else rel
        jobs.append(Job(p, rel.as_posix(), out_dir / base))
    return jobs


def _walk(root: Path):
    """Every file under `root`, following symlinked folders (asset libraries are often linked)."""
    for folder, dirs, files in os.walk(root, followlinks=True):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        yield from (Path(folder) / f for f in files)


def run_job(job: Job, config: BatchConfig, overrides: dict, cache_dir: str | None) -> dict:
    """Bake one asset; never raises: failures come back as one-line errors in the record."""
    t0 = time.perf_counter()
    record = {"asset": str(job.path), "outputs": []}
    try:
        options = config.options_for(job.rel, overrides)
        job.out_base.parent.mkdir(parents=True, exist_ok=True)
        bake = bake_asset if options.budget_rmse is None else bake_within_budget
        result = bake(job.path, options, job.out_base, StageCache(cache_dir))
        record["outputs"] = [str(p) for p in result.outputs]
        record["warnings"] = len(result.report.get("warnings", []))
        invalid = [
            f"{fmt}: {v['errors']} validation error(s)"
            for fmt, v in result.report.get("validation", {}).items()
            if v.get("errors")
        ]
        if invalid:
            record.update(status="failed", error=f"{job.path}: exported files are invalid ({'; '.join(invalid)}); see the report")
        else:
            record["status"] = "up-to-date" if result.up_to_date else "ok"
    except AssetError as e:
        record.update(status="failed", error=str(e))
    except (MaterialError, ConfigError, ValueError, OSError) as e:
        message = str(e).splitlines()[0] if str(e) else type(e).__name__
        record.update(status="failed", error=message if str(job.path) in message else f"{job.path}: {message}")
    except Exception as e:  # a bug must not stop the batch; the traceback's last frame goes in the record
        frame = traceback.extract_tb(e.__traceback__)[-1]
        record.update(
            status="failed",
            error=f"{job.path}: internal error {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''} "
            f"(at {Path(frame.filename).name}:{frame.lineno})",
        )
    record["seconds"] = round(time.perf_counter() - t0, 3)
    return record


def run_batch(
    paths: list[Path], out_dir: Path, config: BatchConfig, overrides: dict, *, jobs: int = 1,
    cache_dir: str | None = None, progress: bool = True,
) -> dict:
    """Bake every asset under `paths` into `out_dir`; returns (and writes) the batch summary."""
    t0 = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    todo = find_assets(paths, out_dir)
    records: list[dict] = []
    bar = tqdm(total=len(todo), unit="asset", disable=not progress, leave=False)
    if jobs <= 1:
        for job in todo:
            bar.set_description(job.rel)
            records.append(run_job(job, config, overrides, cache_dir))
            bar.update()
    else:
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
            futures = {pool.submit(run_job, j, config, overrides, cache_dir): j for j in todo}
            for fut in cf.as_completed(futures):
                records.append(fut.result())
                bar.update()
        order = {str(j.path): i for i, j in enumerate(todo)}
        records.sort(key=lambda r: order[r["asset"]])
    bar.close()
    summary = {
        "assets": records,
        "ok": sum(r["status"] in ("ok", "up-to-date") for r in records),
        "failed": sum(r["status"] == "failed" for r in records),
        "seconds": round(time.perf_counter() - t0, 3),
    }
    with atomic_path(out_dir / "batch.json") as tmp:
        Path(tmp).write_text(json.dumps(summary, indent=1))
    return summary
