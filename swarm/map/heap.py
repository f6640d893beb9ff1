"""Give the C heap's free pages back to the system after a large, short-lived piece of work.

glibc keeps freed memory of allocations below its mmap threshold (which grows, up to 32 MB,
each time a larger block is freed) in the heap for reuse, and returns only the top of it. An
agent that takes the team map's snapshot in a few hundred chunks (the campus floor: 258 of
them, 68 MB) keeps some of their pages resident afterwards; ``malloc_trim(0)`` returns them
(``swarm bench agent-memory --server``: RSS after the catch-up 359 -> 349 MB, after a resync
421 -> 403 MB; before the chunks were placed as they came, 40 MB after the catch-up).
"""

from __future__ import annotations

import ctypes
import ctypes.util
from functools import cache


@cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None (another C library, or none found)."""
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name).malloc_trim if name else None
    except (OSError, AttributeError):
        return None


def trim() -> bool:
    """Return the heap's free pages to the system (glibc); False where it cannot (a no-op)."""
    fn = _malloc_trim()
    if fn is None:
        return False
    fn(0)
    return True
