"""Telling the user while Numba compiles a role's kernels (a first run: a minute or two).

Numba compiles a ``@njit(cache=True)`` kernel on its first call and keeps the machine code in
its cache (:mod:`swarm.compiled_cache`); a later process loads it in well under a second. On
a first run a role spent minutes in its warm-up without a word. Within
:func:`compile_progress` each compilation is said as it starts (Numba's ``numba:compile``
event), ``compiling kernel n of m: module.function``, after one line that says what is going
on, and the count and time at the end; a role whose kernels all load from the cache says
nothing.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

from numba.core import event


def cache_location() -> str:
    """Where Numba keeps the compiled kernels, in words."""
    return os.environ.get("NUMBA_CACHE_DIR") or "__pycache__ beside the sources"


def is_cached(kernel) -> bool | None:
    """Whether Numba's cache holds a compiled version of ``kernel`` (a ``@njit(cache=True)``
    function) for its current source; None when that cannot be told (Numba's cache index is not
    public API: a layout this code does not know answers None, never an error)."""
    try:
        return bool(kernel._cache._cache_file._load_index())
    except Exception:  # noqa: BLE001 (any change of Numba's internals means "cannot tell")
        return None


@contextmanager
def compile_progress(kernels: Sequence, say: Callable[[str], None] | None, role: str = "") -> Iterator[None]:
    """Within the block, tell ``say`` (a role's log or print) about every kernel Numba compiles.

    ``kernels``: the ``@njit(cache=True)`` functions the block compiles on a first run (each
    warm-up names them: ``WARM_UP_KERNELS``); m is the number of them not in the cache yet.
    ``role`` prefixes each line (``r1: ``). A kernel that a compiling one calls compiles as
    part of it and is not counted; a kernel outside ``kernels`` that compiles is counted, and
    m grows with it.
    """
    if say is None:
        yield
        return
    prefix = f"{role}: " if role else ""
    progress = _Progress(say, prefix, sum(1 for k in kernels if is_cached(k) is not True))
    start = time.monotonic()
    with event.install_listener("numba:compile", progress):
        yield
    if progress.count:
        took = f"{time.monotonic() - start:.1f} s"
        say(f"{prefix}compiled {progress.count} kernel(s) in {took}; later runs load them from the cache")


class _Progress(event.Listener):
    """A ``numba:compile`` listener: one line as each top-level kernel starts compiling.

    ``count`` is the number of kernels compiled: a kernel compiled again for other argument
    types (a second signature) is said as such and not counted twice."""

    def __init__(self, say: Callable[[str], None], prefix: str, expected: int) -> None:
        self.say, self.prefix, self.expected = say, prefix, expected
        self.count = 0
        self._numbers: dict[str, int] = {}  # kernel name -> its number in the lines
        self._depth = 0
        self._lock = threading.Lock()

    def on_start(self, ev: event.Event) -> None:
        with self._lock:
            self._depth += 1
            if self._depth > 1:  # a kernel the compiling one calls: part of it
                return
            func = ev.data["dispatcher"].py_func
            name = f"{func.__module__}.{func.__qualname__}"
            if name in self._numbers:
                number = self._numbers[name]
                self.say(
                    f"{self.prefix}compiling kernel {number} of {self.expected} again, "
                    f"for other argument types: {name}"
                )
                return
            self.count += 1
            self._numbers[name] = self.count
            self.expected = max(self.expected, self.count)
            if self.count == 1:
                verb = "is" if self.expected == 1 else "are"
                self.say(
                    f"{self.prefix}compiling kernels (first run): {self.expected} {verb} not in Numba's "
                    f"cache ({cache_location()}) yet; once, tens of seconds to minutes by the machine..."
                )
            self.say(f"{self.prefix}compiling kernel {self.count} of {self.expected}: {name}")

    def on_end(self, _ev: event.Event) -> None:
        with self._lock:
            self._depth -= 1
