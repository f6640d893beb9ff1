"""The map server's inbox: one bounded FIFO per robot, served round-robin (no I/O).

Zenoh callbacks :meth:`Inbox.offer` each payload under its robot; a robot whose queue is
full (in messages or bytes) has the payload refused and counted, never queued, so a fast
publisher cannot grow the server's memory nor delay the other robots: its agent sends what
is not acked again (docs/protocol.md, "Backpressure"). The worker :meth:`Inbox.take`s a
batch, one payload per robot in turn.
"""

from __future__ import annotations

import threading
from collections import Counter, deque


class Inbox:
    """Per-robot bounded queues of ``bytes`` payloads; thread-safe."""

    def __init__(self, max_messages: int, max_bytes: int) -> None:
        if max_messages < 1 or max_bytes < 1:
            raise ValueError("an inbox holds at least one message and one byte per robot")
        self.max_messages = max_messages
        self.max_bytes = max_bytes
        self._queues: dict[str, deque[bytes]] = {}
        self._bytes: Counter[str] = Counter()
        self._ready: deque[str] = deque()  # robots with something queued, in service order
        self._cond = threading.Condition()
        self._messages = 0
        self._total_bytes = 0
        #: payloads refused because their robot's queue was full, per robot
        self.refused: Counter[str] = Counter()
        self.high_water_messages = 0
        self.high_water_bytes = 0

    def offer(self, robot: str, payload: bytes, mac: bytes | None = None) -> bool:
        """Queue ``payload`` (and the MAC attached to it) under ``robot``; False (counted in
        ``refused``) when its queue is full."""
        with self._cond:
            queue = self._queues.setdefault(robot, deque())
            if len(queue) >= self.max_messages or self._bytes[robot] + len(payload) > self.max_bytes:
                self.refused[robot] += 1
                return False
            if not queue:
                self._ready.append(robot)
            queue.append((payload, mac))
            self._bytes[robot] += len(payload)
            self._messages += 1
            self._total_bytes += len(payload)
            self.high_water_messages = max(self.high_water_messages, self._messages)
            self.high_water_bytes = max(self.high_water_bytes, self._total_bytes)
            self._cond.notify()
            return True

    def take(self, max_items: int, timeout: float) -> list[tuple[str, bytes, bytes | None]]:
        """Up to ``max_items`` ``(robot, payload, mac)``, one robot after the other (round-robin);
        waits up to ``timeout`` seconds for the first, returns [] when none came."""
        with self._cond:
            if not self._ready and not self._cond.wait_for(lambda: bool(self._ready), timeout):
                return []
            batch = []
            while self._ready and len(batch) < max_items:
                robot = self._ready.popleft()
                queue = self._queues[robot]
                payload, mac = queue.popleft()
                self._bytes[robot] -= len(payload)
                self._messages -= 1
                self._total_bytes -= len(payload)
                batch.append((robot, payload, mac))
                if queue:
                    self._ready.append(robot)
            return batch

    def __len__(self) -> int:
        with self._cond:
            return self._messages

    def stats(self) -> dict:
        """``map/stats`` ``inbox``: what is queued now, the high-water marks, refusals per robot."""
        with self._cond:
            return {
                "queued": self._messages,
                "queued_bytes": self._total_bytes,
                "high_water": self.high_water_messages,
                "high_water_bytes": self.high_water_bytes,
                "max_per_robot": self.max_messages,
                "max_bytes_per_robot": self.max_bytes,
                "refused": dict(sorted(self.refused.items())),
            }
