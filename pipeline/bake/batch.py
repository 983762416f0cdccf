"""Batch driver: finds assets under the given paths, bakes each in its own supervised worker process
under a time and a memory limit (`asset_process`; --jobs at once, or on a Dask cluster with --dask:
`batch_dask`), keeps going past bad assets, and writes ``OUT/batch.json``.

A batch killed outright (SIGKILL, power loss) leaves finished assets, which the next batch skips
(`bake.job_key` in their report), and temporary files, which the next batch removes
(`sweep_temporaries`) while no other batch is running on the same folders.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from sssbake.exporters.atomic import atomic_path, temporary_target
from sssbake.pipeline.bake.asset_process import Limits, Task, supervise
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.bake.cache import temporaries as cache_temporaries
from sssbake.pipeline.config import BatchConfig, ConfigError
from sssbake.pipeline.core.errors import AssetError, SssbakeError
from sssbake.pipeline.core.materials import MaterialError
from sssbake.pipeline.mesh.load import SUPPORTED_EXTENSIONS
from sssbake.pipeline.options import BAKE_DEFAULTS


class OutputError(SssbakeError, OSError):
    """The output folder cannot be used or written (a file in the way, read-only, disk full).

    Attributes
    ----------
    summary : dict or None
        The batch summary when the assets ran and only ``batch.json`` could not be written.
    """

    exit_code = 2

    def __init__(self, message: str, summary: dict | None = None):
        super().__init__(message)
        self.summary = summary

    def __str__(self) -> str:
        return self.args[0]


# errno values that mean "no room left" (EFBIG: over the file size limit, RLIMIT_FSIZE or the filesystem's)
_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def os_error_line(path: Path, e: OSError) -> str:
    """One line for `e` met while working on `path`: the file and the problem, and for a full disk or
    a folder we may not write the fix; a temporary's name is given as the file it was written for."""
    if e.errno is None:
        return f"{path}: {e}"
    name = e.filename if isinstance(e.filename, str) else None
    if name is not None and (final := temporary_target(Path(name).name)) is not None:
        name = str(Path(name).with_name(final))
    what = f"{name}: {e.strerror}" if name is not None and name != str(path) else e.strerror
    if e.errno in _FULL:
        return f"{path}: {what}; free some space or give -o a folder on another disk"
    if e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"{path}: {what}; give -o a folder you may write"
    return f"{path}: {what}"


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
    from sssbake.pipeline.bake.asset import bake_asset  # here: a parent that only supervises never needs them
    from sssbake.pipeline.bake.check import bake_within_budget

    t0 = time.perf_counter()
    record = {"asset": str(job.path), "outputs": []}
    try:
        options = config.options_for(job.rel, overrides)
        job.out_base.parent.mkdir(parents=True, exist_ok=True)
        bake = bake_asset if options.budget_rmse is None else bake_within_budget
        _record_result(record, job, bake(job.path, options, job.out_base, StageCache(cache_dir)))
    except AssetError as e:
        record.update(status="failed", error=str(e))
    except OSError as e:
        record.update(status="failed", error=os_error_line(job.path, e))
    except (MaterialError, ConfigError, ValueError) as e:
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


def _record_result(record: dict, job: Job, result) -> None:
    """`record` (`run_job`'s) completed from a `BakeResult`."""
    from sssbake.pipeline.planning.plan import worse_than_lambert

    record["outputs"] = [str(p) for p in result.outputs]
    record["warnings"] = len(result.report.get("warnings", []))
    record["worse_than_lambert"] = worse_than_lambert(result.report)
    invalid = [
        f"{fmt}: {v['errors']} validation error(s)"
        for fmt, v in result.report.get("validation", {}).items()
        if v.get("errors")
    ]
    if invalid:
        record.update(status="failed", error=f"{job.path}: exported files are invalid ({'; '.join(invalid)}); see the report")
    else:
        record["status"] = "up-to-date" if result.up_to_date else "ok"


def up_to_date_record(job: Job, config: BatchConfig, overrides: dict) -> dict | None:
    """`run_job`'s record for a job whose outputs are up to date, None for any other (a worker
    bakes it, or reports its error): starting a worker costs seconds, checking milliseconds."""
    from sssbake.pipeline.bake.asset import up_to_date_result

    t0 = time.perf_counter()
    try:
        options = config.options_for(job.rel, overrides)
        result = up_to_date_result(job.path, options, job.out_base) if options.budget_rmse is None else None
    except (SssbakeError, OSError, ValueError):
        return None
    if result is None:
        return None
    record = {"asset": str(job.path), "outputs": []}
    _record_result(record, job, result)
    record["seconds"] = round(time.perf_counter() - t0, 3)
    return record


def run_batch(
    paths: list[Path], out_dir: Path, config: BatchConfig, overrides: dict, *, jobs: int = 1,
    cache_dir: str | None = None, progress: bool = True, dask: str | None = None, isolate: bool = True,
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
        Assets baked at once, each in its own worker process under its `BakeOptions.asset_timeout_s`
        and `asset_memory_gib` (`asset_process.supervise`).
    cache_dir : str or None
        Stage cache folder; None turns caching off.
    progress : bool
        Show a tqdm bar.
    dask : str or None
        Bake on a Dask cluster instead: a scheduler address or ``local:N`` (`batch_dask.run_on_dask`);
        `jobs` is then unused.
    isolate : bool
        False: bake in this process, one asset at a time, with no limits (`jobs` unused); for
        callers that patch the pipeline in-process (tests) or debug it.

    Returns
    -------
    dict
        ``assets`` (one record per asset, in `find_assets` order), ``ok``, ``failed``,
        ``worse_than_lambert`` (`plan.worse_than_lambert`'s records, each with its ``asset``),
        ``seconds`` and ``temporaries_removed`` (stale temporary files of an interrupted batch
        swept first).

    Raises
    ------
    OutputError
        `out_dir` is a file, cannot be written, or ``batch.json`` could not be written (then with
        the summary).
    FileNotFoundError
        A path in `paths` does not exist.
    """
    t0 = time.perf_counter()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{out_dir}: is a file, not a folder; give -o a folder") from None
    except NotADirectoryError:
        raise OutputError(f"{out_dir}: a file is in the way of this folder; give -o a folder") from None
    except OSError as e:
        raise OutputError(os_error_line(out_dir, e)) from None
    todo = find_assets(paths, out_dir)
    with _batch_lock(out_dir, cache_dir) as (removed, start):
        bar = tqdm(total=len(todo), unit="asset", disable=not progress, leave=False)
        if dask is not None:
            from sssbake.pipeline.bake.batch_dask import run_on_dask

            records = run_on_dask(todo, config, overrides, cache_dir, dask, on_done=bar.update, since=start)
        elif not isolate:
            records = []
            for job in todo:
                bar.set_description(job.rel)
                records.append(run_job(job, config, overrides, cache_dir))
                bar.update()
        else:
            records = [up_to_date_record(job, config, overrides) for job in todo]
            bar.update(sum(r is not None for r in records))
            # Largest input first: with a few long assets, starting them last would leave workers idle.
            order = sorted((i for i, r in enumerate(records) if r is None), key=lambda i: -input_bytes(todo[i].path))
            done = supervise([task_for(todo[i], config, overrides, cache_dir) for i in order], jobs,
                             on_done=lambda _i, _record: bar.update())
            for i, record in zip(order, done):
                records[i] = record
        bar.close()
        summary = {
            "assets": records,
            "ok": sum(r["status"] in ("ok", "up-to-date") for r in records),
            "failed": sum(r["status"] == "failed" for r in records),
            # shipped techniques the pilot measured worse than best-fit Lambert, each with its asset
            "worse_than_lambert": [{"asset": r["asset"], **m} for r in records
                                   for m in r.get("worse_than_lambert", [])],
            "seconds": round(time.perf_counter() - t0, 3),
            "temporaries_removed": removed,
        }
        try:
            with atomic_path(out_dir / "batch.json") as tmp:
                Path(tmp).write_text(json.dumps(summary, indent=1))
        except OSError as e:
            raise OutputError(os_error_line(out_dir / "batch.json", e), summary) from None
    return summary


def task_for(job: Job, config: BatchConfig, overrides: dict, cache_dir: str | None) -> Task:
    """`job` as a supervised task, with its asset's limits (the defaults' when its options are
    impossible: the child then fails with the config's one-line error)."""
    try:
        options = config.options_for(job.rel, overrides)
    except ConfigError:
        options = BAKE_DEFAULTS
    return Task(job, config, overrides, cache_dir, Limits(options.asset_timeout_s, options.asset_memory_gib))


def pin_to_share(index: int, count: int) -> None:
    """Confine this process (every thread, and so its children) to worker `index`'s share of the
    CPUs it may use, split among `count` workers; a no-op where CPU affinity is not available.

    xatlas's thread pool busy-waits on idle cores: unconfined, two workers' atlases each take
    twice as long side by side, while confined to one core it runs as fast as alone
    (benchmarks/README.md#batch-cpu-pinning). Worker threads
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

    At the end, a batch alone again sweeps every temporary older than that moment: what its own
    killed workers left in the stage cache (their output temporaries are gone already,
    `asset_process`). A folder that cannot be written raises OutputError.
    """
    folders = [out_dir] + ([Path(cache_dir)] if cache_dir is not None else [])
    with contextlib.ExitStack() as stack:
        files = []
        for folder in dict.fromkeys(f.absolute() for f in folders):
            try:
                folder.mkdir(parents=True, exist_ok=True)
                files.append(stack.enter_context(open(folder / LOCK_NAME, "a+b")))
            except OSError as e:
                raise OutputError(os_error_line(folder, e)) from None
        start = _now(files[0])
        alone = all(_lock(f, exclusive=True) for f in files)
        removed = sweep_temporaries(out_dir, cache_dir, start if alone else start - STALE_AFTER_S)
        for f in files:
            _lock(f, exclusive=False)  # flock's conversion is not atomic: harmless, nothing of ours exists yet
        yield removed, start
        if all(_lock(f, exclusive=True) for f in files):
            sweep_temporaries(out_dir, cache_dir, _now(files[0]))


def _now(lock_file) -> float:
    # The filesystem's clock (which stamps the temporaries' mtimes, and may not be this machine's
    # on a network share), read by touching the lock file.
    os.utime(lock_file.name)
    return os.stat(lock_file.name).st_mtime


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
