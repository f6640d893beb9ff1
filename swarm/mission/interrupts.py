"""How ``swarm sim`` and ``swarm replay`` take Ctrl-C, SIGTERM and SIGHUP.

The first one stops the run in order: it is raised as :class:`KeyboardInterrupt` in the main
thread while the run goes on, and only noted while the runner stops its roles and writes the
run folder (:meth:`Interrupts.held`), so that the folder is written from what the map server
holds. The second one ends the command at once: every role process still running is killed,
one line on stderr says so, and the process exits with 130 without waiting for anything.

The roles themselves ignore the terminal's SIGINT (:mod:`swarm.child_command`): the runner
stops them, in its own order, with SIGTERM.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: The signals a runner takes as "stop": Ctrl-C, ``kill``, and the terminal going away.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Exit status of a command ended by an interrupt (128 + SIGINT, as shells report it).
INTERRUPTED_EXIT = 130


class Interrupts:
    """The runner's handlers of :data:`STOP_SIGNALS` for the duration of a ``with`` block.

    ``what`` names the run in the messages (``the mission``); ``on_force`` is called on the
    second signal, before the process exits (it kills the roles and says what is left).
    Outside the main thread, where handlers cannot be set, the block runs as it is.
    """

    def __init__(
        self, on_force: Callable[[], None], what: str = "the run", then: str = "writing its run folder"
    ) -> None:
        """``then``: what the first signal goes on to do, for its message."""
        self.on_force = on_force
        self.what = what
        self.then = then
        self.count = 0
        self.first: str | None = None  # the name of the first signal, e.g. "SIGINT"
        self.first_at: float | None = None  # its time.monotonic()
        self._holding = 0
        self._deferring = 0
        self._pending = False  # a first signal came within deferred(): raised at its end
        self._previous: dict[int, object] = {}

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():
            self._previous = {sig: signal.signal(sig, self._handle) for sig in STOP_SIGNALS}
        return self

    def __exit__(self, *_exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    @property
    def interrupted(self) -> bool:
        return self.count > 0

    def since(self) -> str:
        """`` N.N s after SIGINT`` (empty before any signal), for the last line of a run."""
        if self.first_at is None:
            return ""
        return f" {time.monotonic() - self.first_at:.1f} s after {self.first}"

    @contextmanager
    def held(self) -> Iterator[None]:
        """Within the block a first signal is noted, not raised (the run is being stopped and
        written already); a second still ends the command at once."""
        self._holding += 1
        try:
            yield
        finally:
            self._holding -= 1

    @contextmanager
    def deferred(self) -> Iterator[None]:
        """Within the block a first signal is raised only at its end: a block that must not be
        cut in two (a child process started and not yet kept, which nothing would then stop)."""
        self._deferring += 1
        try:
            yield
        finally:
            self._deferring -= 1
        if not self._deferring and self._pending and not self._holding:
            self._pending = False
            raise KeyboardInterrupt

    def _handle(self, signum: int, _frame) -> None:
        self.count += 1
        name = signal.Signals(signum).name
        if self.count > 1:
            say(f"swarm: {name} again: stopping at once")
            self.on_force()
            _flush_and_exit(INTERRUPTED_EXIT)
        self.first, self.first_at = name, time.monotonic()
        key = "Ctrl-C" if signum == signal.SIGINT else name
        then = f", {self.then}" if self.then else ""
        say(f"swarm: {name}: stopping {self.what}{then} ({key} again to stop at once)")
        if self._deferring:
            self._pending = True
        elif not self._holding:
            raise KeyboardInterrupt


def say(line: str) -> None:
    """One line on stderr, whatever became of stdout (a pipe whose reader is gone)."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _flush_and_exit(code: int) -> None:
    """Exit now: no clean-up that could wait (a Zenoh session's close, threads at shutdown)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
