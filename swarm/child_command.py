"""How the runners start ``swarm`` in a child process so that it runs the parent's own copy.

``python -m swarm.cli`` puts the working directory first on ``sys.path``. Started from the
project folder (as the README's quick start is), the children of an installed ``swarm sim``
then imported the checkout's sources while the runner ran the installed copy: two versions of
the code in one mission, and every compiled kernel compiled twice on a first run (the runner's
warm-up filled the installed copy's cache, which the children never read). The children are
started with ``-P`` (no working directory on the path, Python 3.11) and, when the parent's
``swarm`` is not an installed package, with its folder first on ``PYTHONPATH``.

The roles a runner starts leave Ctrl-C to the runner (:func:`leave_interrupts_to_the_runner`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def swarm_argv(*args: str) -> list[str]:
    """``[python, -P, -m, swarm.cli, *args]``: this interpreter, the ``swarm`` command."""
    return [sys.executable, "-P", "-m", "swarm.cli", *args]


def child_environment(**extra: str) -> dict[str, str]:
    """This process's environment plus ``extra``, with the folder holding this process's
    ``swarm`` package first on ``PYTHONPATH`` unless it is a site-packages folder (an installed
    copy, which the child finds there anyway)."""
    env = {**os.environ, **extra}
    root = Path(__file__).resolve().parent.parent
    if not {"site-packages", "dist-packages"} & set(root.parts):
        rest = env.get("PYTHONPATH", "")
        env["PYTHONPATH"] = str(root) + (os.pathsep + rest if rest else "")
    return env


# -- who stops a runner's children ---------------------------------------------------------

#: Set in the environment of the role processes a runner starts (``swarm sim``, ``swarm replay``):
#: the runner, not the terminal, stops them.
STOPPED_BY_RUNNER = "SWARM_STOPPED_BY_RUNNER"


#: OpenCV's thread count in the roles a runner starts, unless the user's environment sets one:
#: every role is a process of its own on the runner's machine, and OpenCV's pool workers spin
#: (``sched_yield``) after each parallel call: about 2,000 yields a second per agent on the
#: 16-robot campus floor, each a context switch among twenty busy processes on two cores.
OPENCV_THREADS = "OPENCV_FOR_THREADS_NUM"


def started_by_runner_environment(**extra: str) -> dict[str, str]:
    """:func:`child_environment` for a role process that its runner stops (SIGTERM, in order),
    with OpenCV on one thread (:data:`OPENCV_THREADS`) unless the environment sets it."""
    return child_environment(
        **{STOPPED_BY_RUNNER: "1", OPENCV_THREADS: os.environ.get(OPENCV_THREADS, "1"), **extra}
    )


def leave_interrupts_to_the_runner() -> None:
    """In a role process a runner started: ignore SIGINT, and unblock it.

    A terminal's Ctrl-C sends SIGINT to its whole foreground process group, the runner and
    every role it started. The roles must not act on it: the runner stops them in its own
    order (agents and world, then the map server once it has given its map) with SIGTERM.
    The runner starts each child with SIGINT blocked (:func:`sigint_blocked`), so that a
    Ctrl-C in the child's first milliseconds waits, pending, until this call discards it.
    Does nothing in a process no runner started.
    """
    if os.environ.get(STOPPED_BY_RUNNER) != "1":
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def stop_signals() -> tuple[signal.Signals, ...]:
    """The signals a role stops on: SIGTERM, and SIGINT unless it is ignored (a process a
    runner started, or a shell's background job: SIGINT ignored at start stays ignored)."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        return (signal.SIGTERM,)
    return (signal.SIGTERM, signal.SIGINT)


@contextmanager
def sigint_blocked() -> Iterator[None]:
    """Block SIGINT in this thread for the block: a child started meanwhile inherits the blocked
    mask (:func:`leave_interrupts_to_the_runner` unblocks it). This process loses no Ctrl-C:
    its other threads take it, or it waits pending until the block ends."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
