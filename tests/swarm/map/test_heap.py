"""swarm.map.heap.trim: returns the C heap's free pages (glibc), a no-op elsewhere."""

import ctypes.util
import sys
from pathlib import Path

import pytest

from swarm.map import heap


def _rss_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


GLIBC = sys.platform.startswith("linux") and ctypes.util.find_library("c") is not None


@pytest.mark.skipif(not GLIBC, reason="glibc's malloc_trim")
def test_trim_returns_freed_small_blocks_to_the_system():
    blocks = [bytes(64_000) for _ in range(2_000)]  # 128 MB written, in blocks below the mmap threshold
    del blocks[:-1]  # the last block pins the heap's top: only a trim returns the pages below it
    before = _rss_kb()
    assert heap.trim()
    assert _rss_kb() < before - 30_000
