"""The coordinator's waiting ``coord/assign`` requests: at most one per robot, served in turn
(no I/O, thread-safe).

An answer takes tens of milliseconds, so a robot that asks faster than that (a loop, a
flood) would keep a plain FIFO full and every other robot's request would wait behind its
backlog, past the agents' timeout. Here a robot's newer request takes the place of its older
one, which is handed back to be refused (the robot only waits for its latest), and robots
are served in the order they first asked; at most ``max_robots`` robots wait at once.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Generic, TypeVar

#: Robots whose requests may wait at once (one request each); more are refused as busy.
MAX_WAITING_ROBOTS = 256

Item = TypeVar("Item")


class RequestQueue(Generic[Item]):
    """Waiting requests keyed by robot: a newer one replaces the older, robots served FIFO."""

    def __init__(self, max_robots: int = MAX_WAITING_ROBOTS) -> None:
        if max_robots < 1:
            raise ValueError(f"max_robots must be >= 1, got {max_robots}")
        self.max_robots = max_robots
        self._waiting: OrderedDict[str, Item] = OrderedDict()
        self._cond = threading.Condition()

    def offer(self, robot: str, item: Item) -> tuple[Item | None, bool]:
        """Queue ``item`` as ``robot``'s request. Returns ``(replaced, taken)``: the robot's
        older waiting request it replaced (None if none), and False when ``max_robots`` other
        robots are waiting already and ``item`` was not queued."""
        with self._cond:
            replaced = self._waiting.get(robot)
            if replaced is None and len(self._waiting) >= self.max_robots:
                return None, False
            self._waiting[robot] = item  # a replaced robot keeps its place in line
            self._cond.notify()
            return replaced, True

    def take(self, timeout: float) -> tuple[str, Item] | None:
        """The request of the robot that has waited longest, or None after ``timeout`` seconds."""
        with self._cond:
            if not self._waiting and not self._cond.wait_for(lambda: bool(self._waiting), timeout):
                return None
            return self._waiting.popitem(last=False)

    def drain(self) -> list[Item]:
        """Every waiting request, removed (to refuse them at stop)."""
        with self._cond:
            items = list(self._waiting.values())
            self._waiting.clear()
            return items

    def __len__(self) -> int:
        with self._cond:
            return len(self._waiting)
