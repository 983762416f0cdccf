"""Hand memory that numpy has freed back to the operating system.

glibc keeps freed blocks in per-thread arenas: after the threaded gather build the process holds
several times its live arrays (benchmarks/README.md#freed-memory). `malloc_trim` returns what was
freed, before the next stage allocates its own arrays on top.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _trim():
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):  # not glibc: nothing to trim
        return None


def release_freed_memory() -> bool:
    """Return the freed heap to the system; False where the C library has no `malloc_trim`."""
    trim = _trim()
    if trim is None:
        return False
    trim(0)
    return True
