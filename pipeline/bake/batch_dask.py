"""Batch on a Dask cluster (``sssbake bake … --dask SCHEDULER``): each asset is one
``dask.distributed`` task supervising `batch.run_job` in a child process under the asset's limits
(`asset_process.supervise`, as the local batch does), so records, outputs, limits and cache behave
as locally; `batch.run_batch` finds the assets, sweeps stale temporaries and writes ``batch.json``.

The workers write the outputs and the stage cache themselves: the inputs, the output folder and
the cache folder must be the same paths on the client and on every worker (a shared filesystem),
and the workers must run the same sssbake and libraries (checked before anything is submitted).

A crash in native code, or an asset over its time or memory limit, ends only its child: a failed
record, the worker lives on. A worker that dies mid-asset (killed, out of memory) loses its task and
the scheduler runs it again elsewhere; after ``allowed-failures`` + 1 dead workers (the
scheduler's setting, `ALLOWED_FAILURES` for ``local:N``) the asset is a failed record with a
one-line error and the batch goes on. The dead worker's child dies with it (`asset_process.child_main`).

A batch interrupted (`asset_process.Interrupted`) cancels its tasks and stops their children on
every worker (`asset_process.stop`): a task that has started runs on when cancelled. A ``local:N``
cluster's workers are started with the stop signals blocked (`asset_process.signals_held`): Ctrl-C
reaches them too, and they end when the batch closes the cluster, without a traceback.
"""

from __future__ import annotations

import hashlib
import logging
import re
import sys
import time
import uuid
from collections.abc import Callable
from concurrent.futures import CancelledError
from dataclasses import replace
from importlib.metadata import PackageNotFoundError, requires, version
from multiprocessing import resource_tracker
from pathlib import Path

from sssbake.pipeline.bake.asset_process import Interrupted, signals_held, stop, supervise
from sssbake.pipeline.bake.batch import Job, input_bytes, task_for, up_to_date_record
from sssbake.pipeline.config import BatchConfig
from sssbake.pipeline.core.errors import SssbakeError

# A task whose worker dies is tried on ALLOWED_FAILURES + 1 workers in all, then is a failed record
# (local:N; a remote scheduler uses its own `distributed.scheduler.allowed-failures`, default 3).
ALLOWED_FAILURES = 2
# run_job never raises, so an exception from a task is the worker's own trouble (it could not
# unpickle the job, say); one more try, perhaps on another worker.
RETRIES = 1
_LOCAL = re.compile(r"local:(\d+)")


class ClusterError(SssbakeError, RuntimeError):
    """The cluster cannot take the batch: no scheduler there, or workers unlike this client."""

    exit_code = 2


def run_on_dask(
    jobs: list[Job], config: BatchConfig, overrides: dict, cache_dir: str | None, scheduler: str, *,
    on_done: Callable[[int, dict], object] | None = None, since: float | None = None,
) -> list[dict]:
    """Bake `jobs` as tasks on the Dask cluster at `scheduler`; one `run_job` record per job.

    Parameters
    ----------
    jobs : list of Job
        From `batch.find_assets`; their paths are made absolute for the workers, the records keep
        them as given.
    config, overrides, cache_dir
        As for `batch.run_job`.
    scheduler : str
        A scheduler address (``tcp://host:8786``), or ``local:N``: a LocalCluster of N
        single-threaded worker processes on 127.0.0.1, closed when the batch ends.
    on_done : callable, optional
        Called with a job's index and its record as each ends.
    since : float, optional
        The batch's start on the output filesystem's clock: an asset found up to date whose report
        is newer was baked by this batch (a task run again after its worker died with the result)
        and is recorded ``ok``.

    Returns
    -------
    list of dict
        In the order of `jobs`. A task that failed on the cluster (its workers kept dying, it was
        cancelled) is a failed record with a one-line error naming the file.

    Raises
    ------
    ClusterError
        ``local:N`` with N < 1, an unreachable scheduler, or workers whose sssbake or libraries
        differ from this process's.
    asset_process.Interrupted
        Once the batch's tasks are cancelled and their children stopped (`on_done` is called for a
        job whose outputs are then up to date, its record not yet come).
    """
    import dask
    from distributed import Client, LocalCluster

    if not jobs:
        return []
    local = _LOCAL.fullmatch(scheduler)
    if scheduler.startswith("local") and (local is None or int(local[1]) < 1):
        raise ClusterError(f"--dask {scheduler}: local clusters are written local:N, N >= 1 worker processes")
    cluster = None
    try:
        if local is not None:
            try:
                # Non-daemonic workers may fork their assets' children from a preloaded fork server
                # (a daemonic one must start a fresh interpreter per asset, `asset_process`).
                resource_tracker.ensure_running()  # before `signals_held`, which it would undo
                with dask.config.set({"distributed.worker.daemon": False}), signals_held():
                    cluster = LocalCluster(
                        n_workers=int(local[1]), threads_per_worker=1, processes=True, host="127.0.0.1",
                        dashboard_address=None, silence_logs=logging.ERROR,
                        # the scheduler's HTTP routes (health, metrics) always listen: any free loopback port
                        scheduler_kwargs={"allowed_failures": ALLOWED_FAILURES, "dashboard": False,
                                          "dashboard_address": "127.0.0.1:0"},
                        # no worker memory ceiling: each asset's child has its own (asset_memory_gib)
                        memory_limit=0,
                    )
            except (RuntimeError, OSError) as e:
                # workers are spawned: a script that starts a batch needs `if __name__ == "__main__":`
                why = _first_line(e).rstrip(".")
                raise ClusterError(f"--dask {scheduler}: cannot start a local Dask cluster ({why}; a script needs "
                                   "its batch under `if __name__ == \"__main__\":`)") from None
        try:
            client = Client(cluster if cluster is not None else scheduler, set_as_default=False)
        except (OSError, TimeoutError) as e:
            raise ClusterError(f"--dask {scheduler}: cannot reach the Dask scheduler ({_first_line(e)})") from None
        with client:
            _check_workers(client, scheduler)
            return _run(client, jobs, config, overrides, cache_dir, on_done,
                        pin=int(local[1]) if local is not None else None, since=since)
    finally:
        if cluster is not None:
            cluster.close()


def _run(client, jobs, config, overrides, cache_dir, on_done, pin: int | None, since: float | None) -> list[dict]:
    from distributed import as_completed

    # Workers may run elsewhere: absolute paths (the output paths already are, `find_assets`).
    cache = str(Path(cache_dir).absolute()) if cache_dir is not None else None
    token = uuid.uuid4().hex[:12]  # several batches may share a scheduler: keys of their own
    # Largest input first: with a few long assets, starting them last would leave workers idle.
    pending = iter(sorted(range(len(jobs)), key=lambda i: -input_bytes(jobs[i].path)))
    futures: dict = {}
    started: dict = {}
    # Results are fetched as each task ends: one left in a worker's memory is lost with the worker,
    # and the task then runs again (and finds its outputs up to date).
    done = as_completed(loop=client.loop, with_results=True, raise_errors=False)  # not the default client

    def top_up() -> None:
        # No more tasks out than worker threads: the scheduler would otherwise queue the rest on
        # busy workers, and a worker's death counts against every task queued there, so one asset
        # that kills its workers could use up an innocent one's allowed failures.
        slots = max(1, sum(client.nthreads().values()))
        while len(futures) < slots and (i := next(pending, None)) is not None:
            job = jobs[i]
            task = task_for(replace(job, path=job.path.absolute()), config, overrides, cache)
            fut = client.submit(_run_supervised, pin, token, task, key=(f"sssbake-bake-{token}", i), pure=False,
                                retries=RETRIES)
            futures[fut], started[fut] = i, time.perf_counter()
            done.add(fut)

    records: list[dict | None] = [None] * len(jobs)
    try:
        top_up()
        for fut, result in done:
            i = futures.pop(fut)
            job = jobs[i]
            if fut.status == "finished":
                records[i] = _as_given(result, job, since)
            else:
                records[i] = {"asset": str(job.path), "outputs": [], "status": "failed",
                              "error": _task_error(job, CancelledError() if fut.status == "cancelled"
                                                   else fut.exception()),
                              "seconds": round(time.perf_counter() - started[fut], 3)}
            fut.release()  # the record is copied; the scheduler may forget the task
            if on_done is not None:
                on_done(i, records[i])
            top_up()
    except Interrupted:
        with signals_held():
            client.cancel(list(futures))
            client.run(stop, token, on_error="ignore")
            # a task that finished as the batch stopped, before its record came: its outputs tell
            for i, job in enumerate(jobs):
                if records[i] is None and (record := up_to_date_record(job, config, overrides)) is not None:
                    records[i] = _as_given(record, job, since)
                    if on_done is not None:
                        on_done(i, records[i])
        raise
    return records


def _run_supervised(count: int | None, token: str, task) -> dict:
    """`task`'s record from a supervised child of this worker (`asset_process.supervise`, for the
    batch `token`); on worker `name` of a ``local:count`` cluster the child is confined to the
    worker's share of the CPUs (`batch.pin_to_share`; a restarted worker keeps its name, and so its
    share)."""
    pin = None
    if count is not None:
        try:
            from distributed import get_worker

            pin = (int(get_worker().name), count)
        except (ValueError, TypeError):  # not a LocalCluster worker of ours: run unconfined
            pass
    return supervise([task], pin=pin, tag=token)[0]


def _as_given(record: dict, job: Job, since: float | None) -> dict:
    """`record` with the asset's path as the client gave it (the worker saw it absolute), and
    ``ok`` for an asset this batch baked and then found up to date (`run_on_dask`'s `since`)."""
    worker_path = str(job.path.absolute())
    record["asset"] = str(job.path)
    if "error" in record and record["error"].startswith(worker_path):
        record["error"] = str(job.path) + record["error"][len(worker_path):]
    if record["status"] == "up-to-date" and since is not None:
        reports = [p for p in record["outputs"] if p.endswith(".report.json")]
        try:
            if reports and Path(reports[0]).stat().st_mtime >= since:
                record["status"] = "ok"
        except OSError:
            pass
    return record


def _task_error(job: Job, e: BaseException) -> str:
    """One line for a task that ended without a record, with exception `e`."""
    from distributed import KilledWorker

    if isinstance(e, CancelledError):
        return f"{job.path}: cancelled on the Dask cluster (the scheduler went away or dropped this client)"
    if isinstance(e, KilledWorker):
        return (f"{job.path}: {e.allowed_failures + 1} Dask workers died while baking it (killed, out of memory or "
                "a crash in native code); the workers' logs say which")
    return f"{job.path}: failed on a Dask worker: {type(e).__name__}: {_first_line(e)}"


def _check_workers(client, scheduler: str) -> None:
    """Raise ClusterError when a worker runs other sssbake code or library versions than this client.

    Outputs are byte-identical across machines only with the same code and libraries, and a
    report's `job_key` names sssbake's version alone. Workers that join later are not checked.
    """
    mine = _environment()
    theirs = client.run(_environment, on_error="return")
    for worker, env in sorted(theirs.items()):
        if isinstance(env, BaseException):
            raise ClusterError(f"--dask {scheduler}: worker {worker} cannot run sssbake "
                               f"({type(env).__name__}: {_first_line(env)}); install the same sssbake there")
        differ = [f"{k} {env.get(k)} there, {v} here" for k, v in mine.items() if env.get(k) != v]
        if differ:
            raise ClusterError(f"--dask {scheduler}: worker {worker} differs from this client: {'; '.join(differ)}")


def _environment() -> dict[str, str]:
    """Python's (major.minor), sssbake's and its dependencies' versions, and a digest of sssbake's
    own source."""
    env = {"python": ".".join(map(str, sys.version_info[:2])), "sssbake": version("sssbake"),
           "sssbake source": _source_digest()}
    for req in requires("sssbake") or []:
        if "extra ==" in req:
            continue
        name = re.match(r"[A-Za-z0-9_.\-]+", req)[0]
        try:
            env[name] = version(name)
        except PackageNotFoundError:
            env[name] = "missing"
    return env


def _source_digest() -> str:
    """SHA-256 over the pipeline's and exporters' .py, .json and .mjs files (an editable install's
    version never changes)."""
    from sssbake import exporters, pipeline

    h = hashlib.sha256()
    for package in (pipeline, exporters):
        root = Path(package.__file__).parent
        for p in sorted(root.rglob("*")):
            if p.is_file() and p.suffix in (".py", ".json", ".mjs") and "__pycache__" not in p.parts:
                h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:16]


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
