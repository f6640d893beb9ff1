"""Log lines a remote peer can trigger, bounded: one line per reason per interval, with counts.

A stranger on an open bus can send a malformed message thousands of times a second; a role
that logged each would fill its disk and bury everything else in its log. :class:`LogLimiter`
logs the first message of a reason at once, then at most one line of that reason per
``interval_s`` seconds, saying how many were left unlogged since the last line. Reasons are
the caller's fixed kinds (never text a peer chose), so the limiter's memory is bounded too.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

#: Seconds between two lines of one reason.
LOG_INTERVAL_S = 10.0


class LogLimiter:
    """At most one line per reason per ``interval_s`` on ``logger``; thread-safe."""

    def __init__(
        self,
        logger: logging.Logger,
        interval_s: float = LOG_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger, self.interval_s, self.clock = logger, interval_s, clock
        self._lock = threading.Lock()
        self._last: dict[str, float] = {}
        self._unlogged: dict[str, int] = {}

    def log(self, level: int, reason: str, msg: str, *args, exc_info: bool = False) -> bool:
        """Log ``msg % args`` at ``level`` unless a line of ``reason`` went out less than
        ``interval_s`` ago (then only count it); a line after such a gap ends with
        ``(N more like it unlogged in the last S s)``. True when a line went out."""
        now = self.clock()
        with self._lock:
            last = self._last.get(reason)
            if last is not None and now - last < self.interval_s:
                self._unlogged[reason] = self._unlogged.get(reason, 0) + 1
                return False
            unlogged = self._unlogged.pop(reason, 0)
            self._last[reason] = now
        if unlogged:
            msg = f"{msg} ({unlogged} more like it unlogged in the last {now - last:.0f} s)"
        self.logger.log(level, msg, *args, exc_info=exc_info)
        return True

    def warning(self, reason: str, msg: str, *args) -> bool:
        return self.log(logging.WARNING, reason, msg, *args)

    def exception(self, reason: str, msg: str, *args) -> bool:
        """An error line with the current exception's traceback (in an ``except`` block)."""
        return self.log(logging.ERROR, reason, msg, *args, exc_info=True)
