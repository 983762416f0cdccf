"""Batch driver: finds assets under the given paths, bakes each (in parallel with --jobs, or on a
Dask cluster with --dask: `batch_dask`), keeps going past bad assets, and writes ``OUT/batch.json``.

A batch killed outright (SIGKILL, power loss) leaves finished assets, which the next batch skips
(`bake.job_key` in their report), and temporary files, which the next batch removes
(`sweep_temporaries`) while no other batch is running on the same folders.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import multiprocessing
import os
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from ..exporters.atomic import atomic_path, temporary_target
from .bake import bake_asset
from .plan_check import bake_within_budget
from .cache import StageCache, temporaries as cache_temporaries
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
    cache_dir: str | None = None, progress: bool = True, dask: str | None = None,
) -> dict:
    """Bake every asset under `paths` into `out_dir`; returns (and writes) the batch summary.

    Parameters
    ----------
    paths : list of Path
        Asset files or folders (walked recursively, `find_assets`).
    out_dir : Path
        Output folder; mirrors the input tree.
    config : BatchConfig
        Defaults, per-file rules and material rules.
    overrides : dict
        Options from the command line (`BakeOptions` fields).
    jobs : int
        Assets baked at once in a local process pool (1: in this process).
    cache_dir : str or None
        Stage cache folder; None turns caching off.
    progress : bool
        Show a tqdm bar.
    dask : str or None
        Bake on a Dask cluster instead: a scheduler address or ``local:N`` (`batch_dask.run_on_dask`);
        `jobs` is then unused.

    Returns
    -------
    dict
        ``assets`` (one record per asset, in `find_assets` order), ``ok``, ``failed``, ``seconds``
        and ``temporaries_removed`` (stale temporary files of an interrupted batch swept first).
    """
    t0 = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    todo = find_assets(paths, out_dir)
    with _batch_lock(out_dir, cache_dir) as (removed, start):
        bar = tqdm(total=len(todo), unit="asset", disable=not progress, leave=False)
        if dask is not None:
            from .batch_dask import run_on_dask

            records = run_on_dask(todo, config, overrides, cache_dir, dask, on_done=bar.update, since=start)
        elif jobs <= 1:
            records = []
            for job in todo:
                bar.set_description(job.rel)
                records.append(run_job(job, config, overrides, cache_dir))
                bar.update()
        else:
            records = []
            ctx = multiprocessing.get_context("spawn")
            with cf.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_pool_worker_init,
                                        initargs=(ctx.Value("i", 0), jobs)) as pool:
                # Largest input first: with a few long assets, starting them last would leave workers idle.
                futures = {pool.submit(run_job, j, config, overrides, cache_dir): j
                           for j in sorted(todo, key=lambda j: -input_bytes(j.path))}
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
            "temporaries_removed": removed,
        }
        with atomic_path(out_dir / "batch.json") as tmp:
            Path(tmp).write_text(json.dumps(summary, indent=1))
    return summary


def pin_to_share(index: int, count: int) -> None:
    """Confine this process (every thread, and so its children) to worker `index`'s share of the
    CPUs it may use, split among `count` workers; a no-op where CPU affinity is not available.

    xatlas's thread pool busy-waits on idle cores: unconfined, two workers' atlases each take
    twice as long side by side (the hand of ../shared/assets: 4.6 s alone, 8.3 s each side by
    side, 4.7 s each pinned), while confined to one core it runs as fast as alone. Worker threads
    (BLAS, embree) then use their own share, not the other workers'.
    """
    try:
        cpus = sorted(os.sched_getaffinity(0))
        if count < 2 or not cpus:
            return
        n = len(cpus)
        share = set(cpus[index * n // count:(index + 1) * n // count]) if n >= count else {cpus[index % n]}
        for tid in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(tid), share)
            except ProcessLookupError:  # a thread that just ended
                pass
    except (AttributeError, OSError, ValueError):
        return


def _pool_worker_init(counter, count: int) -> None:
    # Each pool process takes the next index: spawn gives them no identity of their own.
    with counter.get_lock():
        index = counter.value
        counter.value += 1
    pin_to_share(index, count)


def input_bytes(path: Path) -> int:
    """The size of the input file (0 when unreadable): the cue for which asset to start first."""
    try:
        return path.stat().st_size
    except OSError:
        return 0  # a missing file fails in its own job


LOCK_NAME = ".sssbake.lock"
# A temporary untouched this long belongs to no live write, whoever else is running: every writer
# writes its temporary in one go and renames it at once.
STALE_AFTER_S = 3600.0


@contextlib.contextmanager
def _batch_lock(out_dir: Path, cache_dir: str | None) -> Iterator[tuple[int, float]]:
    """Hold a shared lock on `out_dir` (and the cache folder) for the batch; first sweep stale
    temporaries. Yields how many were removed and the batch's start on the filesystem's clock.

    A batch that gets the locks exclusively is the only one running on these folders, so every
    temporary of ours older than its start is a dead run's (`sweep_temporaries`). Otherwise (another
    batch holds them, or the filesystem has no locks) only those untouched for `STALE_AFTER_S` go.
    The locks are advisory ``flock``s on ``<folder>/.sssbake.lock``, which stays in the folder.
    """
    folders = [out_dir] + ([Path(cache_dir)] if cache_dir is not None else [])
    with contextlib.ExitStack() as stack:
        files = []
        for folder in dict.fromkeys(f.absolute() for f in folders):
            folder.mkdir(parents=True, exist_ok=True)
            files.append(stack.enter_context(open(folder / LOCK_NAME, "a+b")))
        # The run's start on the filesystem's clock (which stamps the temporaries' mtimes, and may
        # not be this machine's on a network share).
        os.utime(files[0].name)
        start = os.stat(files[0].name).st_mtime
        alone = all(_lock(f, exclusive=True) for f in files)
        removed = sweep_temporaries(out_dir, cache_dir, start if alone else start - STALE_AFTER_S)
        for f in files:
            _lock(f, exclusive=False)  # flock's conversion is not atomic: harmless, nothing of ours exists yet
        yield removed, start


def _lock(f, *, exclusive: bool) -> bool:
    """Take `f`'s flock without waiting; False when another process holds it or locks are unsupported."""
    try:
        import fcntl
    except ImportError:  # not POSIX: never alone
        return False
    try:
        fcntl.flock(f.fileno(), (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def sweep_temporaries(out_dir: Path, cache_dir: str | None, before: float) -> int:
    """Remove sssbake's temporary files under `out_dir` and `cache_dir` last modified before `before`.

    Only our exact names go: `atomic_path`'s (`atomic.temporary_target`, anywhere under `out_dir`)
    and the stage cache's (`cache.temporaries`). Symlinked folders are not followed. A file that
    vanishes meanwhile (its writer renamed it) or cannot be removed is skipped.

    Parameters
    ----------
    out_dir : Path
        The batch's output folder.
    cache_dir : str or None
        The stage cache folder (may lie inside `out_dir`, or elsewhere).
    before : float
        A POSIX time on the filesystem's clock; newer files are left alone.

    Returns
    -------
    int
        How many files were removed.
    """
    removed = 0

    def drop(path: Path) -> None:
        nonlocal removed
        try:
            if path.lstat().st_mtime < before:
                path.unlink()
                removed += 1
        except OSError:  # gone meanwhile (its writer renamed it), or not ours to remove: cleaning is best effort
            pass

    for folder, _dirs, files in os.walk(out_dir):
        for name in files:
            if temporary_target(name) is not None:
                drop(Path(folder) / name)
    if cache_dir is not None:
        for path in cache_temporaries(cache_dir):
            drop(path)
    return removed
