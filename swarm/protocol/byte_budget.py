"""How many bytes of received payloads may wait to be handled (no I/O).

A Zenoh callback that queues what it receives for another thread must not queue without
bound: anyone on an open bus can send faster than that thread handles. A :class:`ByteBudget`
is taken by the callback for each payload it queues and given back by the thread that takes
it; a payload the budget cannot take is dropped by the caller (and counted there).
"""

from __future__ import annotations

import threading

#: Bytes of merged deltas that may wait in a replica (the honest stream is far below it:
#: 16 robots sharing 50 KB a second each bring 1 MB a second, and replicas keep up).
MAX_QUEUED_MERGED_BYTES = 256 << 20


class ByteBudget:
    """At most ``limit`` bytes taken at once; thread-safe. ``high_water``: the most taken."""

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError(f"a byte budget holds at least one byte, got {limit}")
        self.limit = limit
        self.taken = 0
        self.high_water = 0
        self._lock = threading.Lock()

    def take(self, size: int) -> bool:
        """Take ``size`` bytes; False (nothing taken) when that would pass the limit."""
        with self._lock:
            if self.taken + size > self.limit:
                return False
            self.taken += size
            self.high_water = max(self.high_water, self.taken)
            return True

    def give(self, size: int) -> None:
        """Give back ``size`` bytes taken earlier."""
        with self._lock:
            self.taken -= size
