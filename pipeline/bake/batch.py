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
import shutil
import stat
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from sssbake.exporters.atomic import atomic_path, is_temporary
from sssbake.pipeline.bake.asset_process import Interrupted, Limits, Task, supervise
from sssbake.pipeline.bake.cache import StageCache
from sssbake.pipeline.bake.cache import temporaries as cache_temporaries
from sssbake.pipeline.bake.os_errors import os_error_line
from sssbake.pipeline.bake.staging import is_staging
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


@dataclass(frozen=True)
class Job:
    """One asset to bake: its path, its path relative to the input root, and where outputs go;
    `problem`: the one-line error of an entry found unbakeable (`find_assets`), which fails the job
    without its file being opened; `same_as`: for another name of a file or folder found before
    (a symlink, a hard link, a path given twice), that first name, under which it is baked once."""

    path: Path
    rel: str
    out_base: Path
    problem: str | None = None
    same_as: Path | None = None


def find_assets(paths: list[Path], out_dir: Path) -> list[Job]:
    """Every supported file under `paths` (folders walked recursively, `_walk`), mirrored under `out_dir`.

    Files inside `out_dir` and hidden files and folders are skipped. Two inputs that would share an
    output name (``a.obj`` and ``a.ply``) keep their extension in it (``a.obj.glb``). Symlinked
    folders are followed (asset libraries are often linked), each real folder walked once.

    One real file (device and inode) is one job, under the first name found: paths in the order
    given; in each, names in real folders, then in symlinked folders, then symlinks to files, in
    sorted order. Another name for it (a symlink, a hard link, a folder given twice) would bake the
    same bytes again into outputs of their own, or two jobs would write the same outputs at once;
    it is a job with `Job.same_as` instead, which bakes nothing and says so (so does a second name
    of a folder: a symlinked folder that holds itself, ``loop -> .``, ends the walk there).

    An entry that cannot be baked is a job with its `Job.problem`: one with a supported extension
    that is not a regular file (a FIFO, whose open would block; a socket, a device), a symlink to
    nothing, a file that may not be read; and whatever its name, a symlink loop (``a -> b -> a``), a
    folder that cannot be listed.

    Raises
    ------
    FileNotFoundError
        A path in `paths` does not exist (not even as a dangling symlink).
    """
    out_dir = out_dir.resolve()
    found: list[tuple[Path, Path, str | None, Path | None]] = []
    # (st_dev, st_ino) of the folders walked and the files found (`_file`), each with its first name
    seen: dict[tuple, Path] = {}
    for root in paths:
        root = Path(root)
        if root.is_dir():
            # the root itself is named when it cannot be listed
            found += sorted((p, p.relative_to(root) if p != root else Path(root.absolute().name or "root"), *rest)
                            for p, *rest in _walk(root, str(out_dir), seen))
        elif os.path.lexists(root):  # a file given by name is baked whatever its extension
            found += [(root, Path(root.name), *rest) for _, *rest in _found(root, seen)]
        else:
            raise FileNotFoundError(f"{root}: no such file or folder")
    stems: dict[Path, int] = {}
    for _, rel, _, _ in found:
        stems[rel.with_suffix("")] = stems.get(rel.with_suffix(""), 0) + 1
    jobs = []
    for p, rel, problem, same_as in found:
        base = rel.with_suffix("") if stems[rel.with_suffix("")] == 1 else rel
        jobs.append(Job(p, rel.as_posix(), out_dir / base, problem, same_as))
    return jobs


def _walk(root: Path, out_dir: str, seen: dict[tuple, Path]) -> Iterator[tuple[Path, str | None, Path | None]]:
    """(path, `Job.problem`, `Job.same_as`) of every entry under `root` that `find_assets` makes a job of.

    Real folders first, depth first, then the symlinked folders found, in order (with the real
    folders under them, and so on), each real folder once (`seen`, shared across the roots): a link
    to a folder already walked is not followed, since its files are found under their other name
    and following it could walk for ever (``loop -> .``); it is named with the folder's first name.
    A link to a folder above the root that holds it is a symlink loop that leads out of what was given.
    Symlinks to files come last, so that a file is named by its real name where it has one in the
    tree. Nothing under the real folder `out_dir` is an input.
    """
    stack = [(root, os.path.realpath(root))]  # folders to walk, each with its real path
    linked: list[tuple[Path, str]] = []  # symlinked folders found, each with the real path of the folder holding it
    links: list[Path] = []  # symlinks to anything else, found with a supported extension or looping
    while stack or linked:
        if not stack:
            link, holder = linked.pop(0)
            target = os.path.realpath(link)
            if _within(holder, target) and not _walked(target, seen):  # above the root: outside what was given
                yield link, f"{link}: a symlink loop: it points to {target}, a folder that holds it; not followed", None
                continue
            stack.append((link, target))
        folder, real = stack.pop()
        if _within(real, out_dir):
            continue
        try:
            st = os.stat(folder)
            if (key := (st.st_dev, st.st_ino)) in seen:
                yield folder, None, seen[key]
                continue
            seen[key] = folder
            with os.scandir(folder) as listing:
                entries = sorted(listing, key=lambda e: e.name)
        except OSError as e:
            yield folder, f"{folder}: cannot read this folder: {e.strerror}", None
            continue
        below = []
        for entry in entries:
            path = folder / entry.name
            if entry.name.startswith("."):
                continue
            if _is_dir(entry):
                if entry.is_symlink():
                    linked.append((path, real))
                else:
                    below.append((path, os.path.join(real, entry.name)))
            elif entry.is_symlink():
                if path.suffix.lower() in SUPPORTED_EXTENSIONS or _loops(path):
                    links.append(path)
            elif path.suffix.lower() in SUPPORTED_EXTENSIONS:
                yield from _found(path, seen)
        stack.extend(reversed(below))  # popped in sorted order
    for path in links:
        if not _within(os.path.realpath(path), out_dir):
            yield from _found(path, seen)


def _found(path: Path, seen: dict[tuple, Path]) -> Iterator[tuple[Path, str | None, Path | None]]:
    """`path`, its problem (`_file`) and the name its file was found under before (None: the first)."""
    key, problem = _file(path)
    if key in seen:
        yield path, None, seen[key]
    else:
        seen[key] = path
        yield path, problem, None


def _walked(folder: str, seen: dict[tuple, Path]) -> bool:
    try:
        st = os.stat(folder)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) in seen


def _is_dir(entry: os.DirEntry) -> bool:
    try:
        return entry.is_dir()
    except OSError:  # a symlink loop, a folder we may not look into: a file entry, whose problem `_file` tells
        return False


def _within(path: str, folder: str) -> bool:
    """Whether the real path `path` is the real path `folder` or lies under it."""
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def _loops(path: Path) -> bool:
    """Whether the symlink `path` never reaches a file: it leads back to itself (ELOOP)."""
    try:
        os.stat(path)
    except OSError as e:
        return e.errno == errno.ELOOP
    return False


# What a file that is not a regular one is, by `stat.S_IFMT`.
_KINDS = {stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket", stat.S_IFCHR: "a character device",
          stat.S_IFBLK: "a block device", stat.S_IFDIR: "a folder"}


def _file(path: Path) -> tuple[tuple[int, int] | tuple[str], str | None]:
    """What `find_assets` knows of a file entry without opening it: its key for `find_assets`' seen
    set (device and inode; the path itself where no file is reached) and its one-line problem, or
    None when it can be baked."""
    try:
        st = os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return (str(path),), f"{path}: a symlink loop ({_chain(path)})"
        if e.errno in (errno.ENOENT, errno.ENOTDIR) and os.path.islink(path):
            return (str(path),), f"{path}: a symlink to a missing file ({_chain(path)})"
        return (str(path),), f"{path}: cannot read: {e.strerror}"
    key = (st.st_dev, st.st_ino)
    if not stat.S_ISREG(st.st_mode):
        return key, f"{path}: not a regular file ({_KINDS.get(stat.S_IFMT(st.st_mode), 'of an unknown kind')})"
    if not os.access(path, os.R_OK):
        return key, f"{path}: cannot read: permission denied"
    return key, None


def _chain(path: Path) -> str:
    """The symlinks from `path` on, as ``a -> b -> a``: each target as written, up to one seen
    before, a missing one, or 40 (the kernel's limit)."""
    names, here, visited = [path.name], path, {os.path.abspath(path)}
    for _ in range(40):
        try:
            target = os.readlink(here)
        except OSError:  # not a link (the end of the chain), or gone
            break
        names.append(target)
        here = here.parent / target
        if os.path.abspath(here) in visited:
            break
        visited.add(os.path.abspath(here))
    return " -> ".join(names)


def run_job(job: Job, config: BatchConfig, overrides: dict, cache_dir: str | None) -> dict:
    """Bake one asset; never raises: failures come back as one-line errors in the record."""
    if job.problem is not None:
        return {"asset": str(job.path), "outputs": [], "status": "failed", "error": job.problem, "seconds": 0.0}
    if job.same_as is not None:
        return {"asset": str(job.path), "outputs": [], "status": "same-file", "same_as": str(job.same_as),
                "seconds": 0.0}
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
    # why its glTF outputs were not validated (`asset._validate`'s ``skipped``), for the batch's one line
    skipped = [v["skipped"] for v in result.report.get("validation", {}).values() if "skipped" in v]
    if skipped:
        record["validation_skipped"] = skipped[0]
    record["worse_than_lambert"] = worse_than_lambert(result.report)
    # outputs with validation errors of their own fail the bake and are never left (`asset._write`)
    record["status"] = "up-to-date" if result.up_to_date else "ok"


def up_to_date_record(job: Job, config: BatchConfig, overrides: dict) -> dict | None:
    """`run_job`'s record for a job whose outputs are up to date or that `find_assets` found
    unbakeable, None for any other (a worker bakes it, or reports its error): starting a worker
    costs seconds, checking milliseconds."""
    from sssbake.pipeline.bake.asset import up_to_date_result

    if job.problem is not None or job.same_as is not None:
        return run_job(job, config, overrides, None)
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
    asset_process.Interrupted
        Under `asset_process.stop_on_signals`, a stop signal: the workers are killed and cleaned up
        after, nothing more is written (no ``batch.json``), and it holds the records of the assets
        done (`Interrupted.records`).
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
    with _batch_lock(out_dir, cache_dir) as (removed, start), \
            tqdm(total=len(todo), unit="asset", disable=not progress, leave=False) as bar:
        records: list[dict | None] = [None] * len(todo)

        def done(i: int, record: dict) -> None:
            records[i] = record
            bar.update()

        try:
            if dask is not None:
                from sssbake.pipeline.bake.batch_dask import run_on_dask

                run_on_dask(todo, config, overrides, cache_dir, dask, on_done=done, since=start)
            elif not isolate:
                for i, job in enumerate(todo):
                    bar.set_description(job.rel)
                    done(i, run_job(job, config, overrides, cache_dir))
            else:
                for i, job in enumerate(todo):
                    if (record := up_to_date_record(job, config, overrides)) is not None:
                        done(i, record)
                # Largest input first: with a few long assets, starting them last would leave workers idle.
                order = sorted((i for i, r in enumerate(records) if r is None),
                               key=lambda i: -input_bytes(todo[i].path))
                supervise([task_for(todo[i], config, overrides, cache_dir) for i in order], jobs,
                          on_done=lambda k, record: done(order[k], record))
        except Interrupted as e:  # the assets done stay done: the caller counts them, a rerun skips them
            e.records = records
            raise
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

    At the end, or when it is interrupted, a batch alone again sweeps every temporary older than that
    moment: what its own killed workers left in the stage cache (their output temporaries are gone
    already, `asset_process`). A folder that cannot be written raises OutputError.
    """
    # each folder with the option that named it, for the fix an error names (the output folder's when both are one)
    folders = {out_dir.absolute(): "-o"}
    if cache_dir is not None:
        folders.setdefault(Path(cache_dir).absolute(), "--cache-dir")
    with contextlib.ExitStack() as stack:
        files = []
        for folder, option in folders.items():
            try:
                folder.mkdir(parents=True, exist_ok=True)
                files.append(stack.enter_context(open(folder / LOCK_NAME, "a+b")))
            except OSError as e:
                raise OutputError(os_error_line(folder, e, option)) from None
        start = _now(files[0])
        alone = all(_lock(f, exclusive=True) for f in files)
        removed = sweep_temporaries(out_dir, cache_dir, start if alone else start - STALE_AFTER_S)
        for f in files:
            _lock(f, exclusive=False)  # flock's conversion is not atomic: harmless, nothing of ours exists yet
        try:
            yield removed, start
        except Interrupted:  # its workers were killed: what they left in the stage cache goes now too
            _sweep_alone(files, out_dir, cache_dir)
            raise
        _sweep_alone(files, out_dir, cache_dir)


def _sweep_alone(files: list, out_dir: Path, cache_dir: str | None) -> None:
    """At a batch's end, sweep every temporary older than now if it is alone again (`files`' locks)."""
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

    Only our exact names go: `atomic_path`'s (`atomic.is_temporary`, anywhere under `out_dir`), the
    bakes' staging folders (`staging.is_staging`, whole) and the stage cache's (`cache.temporaries`).
    Symlinked folders are not followed. A file that vanishes meanwhile (its writer renamed it) or
    cannot be removed is skipped.

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
        How many files (and staging folders) were removed.
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

    for folder, dirs, files in os.walk(out_dir):
        for name in files:
            if is_temporary(name):
                drop(Path(folder) / name)
        for name in [d for d in dirs if is_staging(d)]:  # a bake's staging folder, whole (`bake.staging`)
            dirs.remove(name)
            try:
                if (Path(folder) / name).lstat().st_mtime < before:
                    shutil.rmtree(Path(folder) / name)
                    removed += 1
            except OSError:
                pass
    if cache_dir is not None:
        for path in cache_temporaries(cache_dir):
            drop(path)
    return removed
