"""Runs stages through the content-hash cache and records what each cost."""

from __future__ import annotations

import resource
import time
import tracemalloc
from contextlib import contextmanager
from dataclasses import dataclass, field

from .cache import StageCache, stage_key


@dataclass
class StageRecord:
    name: str
    seconds: float = 0.0
    runs: int = 0
    cached: int = 0
    corrupt: int = 0
    skipped: str | None = None

    def to_json(self) -> dict:
        out = {"seconds": round(self.seconds, 4), "runs": self.runs, "cached": self.cached}
        if self.corrupt:
            out["corrupt_cache_entries"] = self.corrupt
        if self.skipped:
            out["skipped"] = self.skipped
        return out


@dataclass
class StageRunner:
    """Runs `fn(*args)` for a stage unless the cache holds the result for the same key.

    Records per stage: seconds spent (cache loads included), how many runs were served from the
    cache, and the process's peak resident memory after the stage.
    """

    cache: StageCache
    trace_memory: bool = False
    records: dict[str, StageRecord] = field(default_factory=dict)
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    peak_traced_mb: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def _measure(self, rec: StageRecord):
        # tracemalloc sees numpy's allocations, so its peak is the stage's own working set;
        # ru_maxrss is the process's high-water mark so far (C++ libraries included).
        if self.trace_memory:
            if not tracemalloc.is_tracing():
                tracemalloc.start()
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
        t0 = time.perf_counter()
        yield
        rec.seconds += time.perf_counter() - t0
        rec.runs += 1
        if self.trace_memory:
            peak = (tracemalloc.get_traced_memory()[1] - base) / 2**20
            self.peak_traced_mb[rec.name] = max(self.peak_traced_mb.get(rec.name, 0.0), peak)
        self.peak_rss_mb[rec.name] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    def run(self, name: str, version: int, upstream: str, params: dict, fn, *args, fresh=None):
        """Returns (result, key); `key` is the upstream key of the stages that consume the result.

        `fresh(value)`, when given, says whether a cached value still holds (it depends on more
        than its key, e.g. on files the stage read); a stale one is recomputed and replaced.
        """
        key = stage_key(upstream, name, version, params)
        rec = self.records.setdefault(name, StageRecord(name))
        with self._measure(rec):
            damaged = len(self.cache.corrupt)
            value = self.cache.get(key)
            rec.corrupt += len(self.cache.corrupt) - damaged
            if value is not None and fresh is not None and not fresh(value):
                value = None
            if value is None:
                value = fn(*args)
                self.cache.put(key, value)
            else:
                rec.cached += 1
        return value, key

    @contextmanager
    def timed(self, name: str):
        """Time an uncached step (exports, validation) under `name`."""
        with self._measure(self.records.setdefault(name, StageRecord(name))):
            yield

    def skip(self, name: str, reason: str) -> None:
        self.records.setdefault(name, StageRecord(name)).skipped = reason

    def to_json(self) -> dict:
        out = {}
        for name, rec in self.records.items():
            out[name] = {**rec.to_json(), "peak_rss_mb": round(self.peak_rss_mb.get(name, 0.0), 1)}
            if name in self.peak_traced_mb:
                out[name]["peak_traced_mb"] = round(self.peak_traced_mb[name], 1)
        return out
