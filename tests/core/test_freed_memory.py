"""Handing freed heap memory back to the system."""

import ctypes.util

import numpy as np
import pytest

from sssbake.pipeline.core.freed_memory import release_freed_memory


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


@pytest.mark.skipif("libc.so" not in (ctypes.util.find_library("c") or ""), reason="needs glibc's malloc_trim")
def test_freed_heap_blocks_go_back_to_the_system():
    # Freeing a 16 MB array raises glibc's mmap threshold to 16 MB, so the 1 MB arrays after it
    # come from the heap; freeing all but every 40th leaves holes that free() keeps.
    grow = np.ones(2 << 20)
    del grow
    blocks = [np.ones(1 << 17) for _ in range(400)]
    keep = blocks[::40]
    del blocks
    before = _rss_mb()
    assert release_freed_memory() is True
    assert _rss_mb() < before - 250  # most of the ~390 MB freed
    assert all(float(b[0]) == 1.0 for b in keep)  # live arrays untouched
