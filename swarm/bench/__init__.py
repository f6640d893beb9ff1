"""Benchmarks that print their figures (``swarm bench ...``)."""

import statistics
import time
from collections.abc import Callable


def timed_seconds(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """(fastest, median) wall seconds of ``repeat`` (at least one) timed calls of ``fn``."""
    times = []
    for _ in range(max(repeat, 1)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    times.sort()
    return times[0], float(statistics.median(times))


def best_seconds(fn: Callable[[], object], repeat: int) -> float:
    """The fastest of ``repeat`` timed calls of ``fn``."""
    return timed_seconds(fn, repeat)[0]


def best_cpu_seconds(fn: Callable[[], object], repeat: int) -> float:
    """The least CPU time of this thread over ``repeat`` calls of ``fn`` (steadier on a shared machine)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.thread_time()
        fn()
        best = min(best, time.thread_time() - t0)
    return best


def stop_server(server, sessions, timeout: float = 60.0) -> None:
    """Close the benchmark's Zenoh ``sessions``, then SIGTERM the ``server`` process and wait
    ``timeout`` seconds for it (SIGKILL after that)."""
    import subprocess

    for session in sessions:
        session.close()
    server.terminate()
    try:
        server.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        server.kill()
