"""The map server's acks paused while its store cannot write (disk full, I/O error), and resumed
by themselves when it can again (docs/protocol.md, "Store layout").

A delta is acked only once its log record is fsynced; when an append fails, its deltas are
neither applied nor acked and their senders resend them. So on a full disk nothing acked is
lost, but the worker must not spin on the disk or fill the log with one line per failure:
:class:`DiskPause` says ``disk full: acks paused`` once, lets the worker try again every
``retry_s`` (taking nothing from the inbox meanwhile, so it refuses what does not fit and the
agents resend), logs at most one line per ``log_every_s`` with the counts, and says ``acks
resumed`` at the first append that succeeds. A compaction that fails (or finds no room) is
tried again after ``compact_retry_s``, not at every batch.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from map_server.store import is_no_space
from swarm.log_limit import LOG_INTERVAL_S, LogLimiter

#: Seconds between two appends tried while the acks are paused.
RETRY_S = 1.0
#: Seconds before a compaction that failed is tried again.
COMPACT_RETRY_S = 30.0


class DiskPause:
    """Whether the store's appends are failing, with the counts; thread-safe to read."""

    def __init__(
        self,
        logger: logging.Logger,
        retry_s: float = RETRY_S,
        compact_retry_s: float = COMPACT_RETRY_S,
        log_every_s: float = LOG_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.log, self.retry_s, self.compact_retry_s, self.clock = logger, retry_s, compact_retry_s, clock
        self.log_every_s = log_every_s
        self._limited = LogLimiter(logger, log_every_s, clock)
        self._last_line = 0.0
        self.paused = False
        #: failed appends since the store opened
        self.errors = 0
        self._since = 0.0
        self._failed_appends = 0
        self._refused = 0
        self._compact_after = 0.0

    def failed(self, exc: BaseException, deltas: int) -> None:
        """An append of ``deltas`` deltas failed with ``exc``: pause (or stay paused)."""
        self.errors += 1
        what = "disk full" if is_no_space(exc) else "store I/O error"
        if not self.paused:
            self.paused, self._since = True, self.clock()
            self._failed_appends, self._refused = 0, 0
            self.log.error(
                "%s: acks paused (%s); %d deltas not applied, their senders resend them; trying again "
                "every %g s",
                what,
                exc,
                deltas,
                self.retry_s,
            )
            self._last_line = self._since
        elif self.clock() - self._last_line >= self.log_every_s:
            self._last_line = self.clock()
            self.log.error(
                "%s: acks still paused after %.0f s: %d appends failed, %d deltas refused (%s)",
                what,
                self.clock() - self._since,
                self._failed_appends + 1,
                self._refused + deltas,
                exc,
            )
        self._failed_appends += 1
        self._refused += deltas

    def succeeded(self) -> None:
        """An append went through: resume the acks if they were paused."""
        if self.paused:
            self.paused = False
            self.log.warning(
                "store writes again: acks resumed after %.1f s (%d appends failed, %d deltas refused "
                "meanwhile and left to their senders)",
                self.clock() - self._since,
                self._failed_appends,
                self._refused,
            )

    def wait_for_retry(self, stopping: threading.Event) -> None:
        """While paused, wait ``retry_s`` (or until ``stopping``) before the next try."""
        if self.paused:
            stopping.wait(self.retry_s)

    def compaction_due(self) -> bool:
        return self.clock() >= self._compact_after

    def compaction_failed(self, exc: BaseException) -> None:
        """A compaction failed or found no room: the old snapshot and log stay; try later."""
        self._compact_after = self.clock() + self.compact_retry_s
        self._limited.log(
            logging.WARNING,
            "compaction",
            "compaction put off, the log goes on (next try in %.0f s): %s",
            self.compact_retry_s,
            exc,
        )
