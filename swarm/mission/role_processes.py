"""Starting, watching and stopping the roles of a run on one machine, as child processes.

``swarm sim`` (:mod:`swarm.mission.runner`) and ``swarm replay`` (:mod:`swarm.mission.replay_run`)
both start the map server and other roles as ``swarm ...`` child processes, each with its log in
the run folder; wait for the map server to answer; stop the children with SIGTERM (SIGKILL after
a timeout) while holding Ctrl-C and SIGTERM off the stopping; and fetch the server's final map.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from swarm.child_command import child_environment, swarm_argv
from swarm.map.coverage_map import CoverageMap
from swarm.mission.role_failure import RoleError
from swarm.mission.team_monitor import TeamMonitor
from swarm.protocol.map_client import MapClient, MapQueryError, MapServerUnavailable


def start_role(args: list[str], log_path: Path) -> subprocess.Popen:
    """Start ``swarm ARGS...`` as a child process, its output (stdout and stderr) in ``log_path``."""
    log = open(log_path, "w")  # noqa: SIM115 (kept open for the child's lifetime)
    child = subprocess.Popen(
        swarm_argv(*args), stdout=log, stderr=subprocess.STDOUT, env=child_environment(PYTHONUNBUFFERED="1")
    )
    child.log_path = log_path  # for why_it_exited
    return child


def why_it_exited(child: subprocess.Popen) -> str:
    """``exited with code N``, with the last ``error:`` line of the child's log when it has one
    (``swarm: error: FILE: FIELD: ...``), so that the user need not open the log."""
    reason = f"exited with code {child.returncode}"
    log_path = getattr(child, "log_path", None)
    try:
        lines = Path(log_path).read_text(errors="replace").splitlines() if log_path else []
    except OSError:
        lines = []
    errors = [line.strip() for line in lines if "error:" in line]
    return f"{reason}: {errors[-1]}" if errors else f"{reason} (see {Path(log_path).name})"


def stop_roles(procs: list[subprocess.Popen], timeout: float = 10.0) -> None:
    """SIGTERM each running child, wait for them all up to ``timeout`` s in total, SIGKILL the late ones."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@contextmanager
def shielded_from_interrupts() -> Iterator[None]:
    """Run a cleanup to its end though Ctrl-C or SIGTERM arrive meanwhile: they are held, and
    raised as one KeyboardInterrupt after it. (Raised in the middle of stopping the roles, the
    interrupt left the world and the map server running after the runner had exited.) Outside
    the main thread, where signal handlers cannot be set, the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous = {
        sig: signal.signal(sig, lambda signum, _frame: held.append(signum))
        for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if held:
        raise KeyboardInterrupt


def wait_for_server(client: MapClient, server: subprocess.Popen, timeout: float = 60.0) -> None:
    """Wait until the map server answers map/stats (it may be recovering its store)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RoleError(f"the map server {why_it_exited(server)}")
        try:
            client.stats()
            return
        except (MapServerUnavailable, MapQueryError):
            time.sleep(0.2)
    raise RoleError(f"the map server did not answer within {timeout:g} s (see server.log)")


def final_server_map(client: MapClient, monitor: TeamMonitor, timeout: float = 20.0) -> CoverageMap | None:
    """The server's map once it has applied every delta the monitor saw (None if it never did)."""
    deadline = time.monotonic() + timeout
    expected = monitor.applied
    while time.monotonic() < deadline:
        try:
            stats = client.stats()
            if int(stats.get("deltas_applied", 0)) >= expected:
                snap = client.snapshot()
                return CoverageMap(snap.grid, monitor.cmap.sensor, snap.lam, snap.eta)
        except (MapServerUnavailable, MapQueryError) as exc:
            print(f"runner: map server: {exc}", file=sys.stderr)
        time.sleep(0.3)
    print("runner: the map server did not catch up with the monitor's deltas", file=sys.stderr)
    return None
