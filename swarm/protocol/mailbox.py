"""A mailbox that keeps the newest message of each key for one consumer (thread-safe, no I/O).

Some messages say how a thing is now: a camera frame, a robot's status, a robot's latest
request for a target. Once a newer one of the same key has come, the older one is worth
nothing, and a first-in first-out queue of them would grow as long as the sender is faster
than the consumer and make the consumer answer the past. A :class:`Mailbox` holds one value
per key: a newer value replaces the older (counted ``replaced``), keys are served in the order
they first came (a key that is replaced keeps its place), and at most ``max_keys`` keys wait at
once: a value for another key is refused (counted ``dropped``), so that anyone on an open bus
sending under invented keys cannot grow the receiver's memory.

Used by the agent's frame inbox (one key), its teammates' statuses (a key per robot), and the
coordinator's statuses and ``coord/assign`` requests (a key per robot).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


@dataclass(frozen=True)
class Posted(Generic[V]):
    """What :meth:`Mailbox.put` did with a value.

    ``accepted``: False when ``max_keys`` other keys were waiting and the value was not kept;
    ``replaced``: the older value of the same key it took the place of (None if none);
    ``first``: the mailbox was empty before it (the put that should wake a consumer)."""

    accepted: bool
    replaced: V | None = None
    first: bool = False


class Mailbox(Generic[K, V]):
    """The newest value of each of at most ``max_keys`` keys, oldest key first.

    Any number of threads may :meth:`put`; a consumer :meth:`take`s one key's value (waiting up
    to a timeout) or :meth:`take_all` of them. Values must not be None (None means "nothing").
    ``replaced`` and ``dropped`` count the values replaced before they were taken and those
    refused for want of room.
    """

    def __init__(self, max_keys: int) -> None:
        if max_keys < 1:
            raise ValueError(f"max_keys must be >= 1, got {max_keys}")
        self.max_keys = max_keys
        self._waiting: OrderedDict[K, V] = OrderedDict()
        self._ready = threading.Condition()
        self._replaced = 0
        self._dropped = 0

    def put(self, key: K, value: V) -> Posted[V]:
        """Leave ``value`` under ``key``, replacing the key's waiting value (see :class:`Posted`)."""
        if value is None:
            raise ValueError("a mailbox value must not be None")
        with self._ready:
            replaced = self._waiting.get(key)
            if replaced is None and len(self._waiting) >= self.max_keys:
                self._dropped += 1
                return Posted(accepted=False)
            first = not self._waiting
            self._waiting[key] = value  # a replaced key keeps its place in line
            if replaced is not None:
                self._replaced += 1
            self._ready.notify()
            return Posted(accepted=True, replaced=replaced, first=first)

    def take(self, timeout: float = 0.0) -> tuple[K, V] | None:
        """The key that has waited longest and its value, removed; waits up to ``timeout``
        seconds for one (0: does not wait); None if none came."""
        with self._ready:
            if not self._waiting and not self._ready.wait_for(lambda: bool(self._waiting), timeout):
                return None
            return self._waiting.popitem(last=False)

    def take_all(self) -> dict[K, V]:
        """Every waiting key and its value, in the order the keys first came, removed."""
        with self._ready:
            waiting = dict(self._waiting)
            self._waiting.clear()
            return waiting

    @property
    def replaced(self) -> int:
        """Values replaced by a newer one of their key before they were taken."""
        with self._ready:
            return self._replaced

    @property
    def dropped(self) -> int:
        """Values refused because ``max_keys`` other keys were waiting."""
        with self._ready:
            return self._dropped

    def __len__(self) -> int:
        with self._ready:
            return len(self._waiting)
