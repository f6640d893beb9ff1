"""Pairing a live stereo camera's left and right images by their header stamps, as
``message_filters``' approximate-time policy does for two streams.

Each image waits in a short queue of its side (``depth``, the subscription's history) until an
image of the other side stamped within ``tolerance`` comes; the two then leave as a pair, and
older images still waiting on either side will never pair (both cameras stamp in order) and are
dropped. An image pushed out of a full queue is dropped too. Every dropped image is counted by
side in ``dropped`` (e.g. ``"left image with no right image within 0.01 s"``).

Pure bookkeeping of (stamp, item); the caller serialises access.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any

SIDES = ("left", "right")


@dataclass
class StereoSync:
    """Left and right items by stamp (s); ``add`` returns the pairs it completes."""

    tolerance: float = 0.01
    depth: int = 5
    dropped: Counter = field(default_factory=Counter)
    _waiting: dict[str, deque] = field(default_factory=lambda: {side: deque() for side in SIDES})

    def reason(self, side: str) -> str:
        other = SIDES[1 - SIDES.index(side)]
        return f"{side} image with no {other} image within {self.tolerance:g} s"

    def add(self, side: str, stamp: float, item: Any) -> list[tuple[float, Any, Any]]:
        """Queue ``item`` of ``side`` ('left' or 'right') stamped ``stamp``; the pairs made, as
        (left stamp, left item, right item) (none or one)."""
        if side not in SIDES:
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        other = SIDES[1 - SIDES.index(side)]
        queue = self._waiting[other]
        best = None
        for k, (t, _) in enumerate(queue):
            if abs(t - stamp) <= self.tolerance and (
                best is None or abs(t - stamp) < abs(queue[best][0] - stamp)
            ):
                best = k
        if best is None:
            mine = self._waiting[side]
            mine.append((stamp, item))
            if len(mine) > 1 and mine[-2][0] > stamp:  # out of order: keep the queue sorted
                self._waiting[side] = mine = deque(sorted(mine, key=lambda pair: pair[0]))
            while len(mine) > self.depth:
                mine.popleft()
                self.dropped[self.reason(side)] += 1
            return []
        partner_stamp, partner = queue[best]
        for _ in range(best + 1):  # the partner and the older ones, which will never pair
            queue.popleft()
        if best:
            self.dropped[self.reason(other)] += best
        mine = self._waiting[side]
        while mine and mine[0][0] < stamp:
            mine.popleft()
            self.dropped[self.reason(side)] += 1
        if side == "left":
            return [(stamp, item, partner)]
        return [(partner_stamp, partner, item)]

    def waiting(self) -> int:
        """Images waiting for their partner."""
        return sum(len(q) for q in self._waiting.values())
