"""Starting, watching and stopping the roles of a run on one machine, as child processes.

``swarm sim`` (:mod:`swarm.mission.runner`) and ``swarm replay`` (:mod:`swarm.mission.replay_run`)
both start the map server and other roles as ``swarm ...`` child processes, each with its log in
the run folder; wait for the map server to answer; stop the children with SIGTERM (SIGKILL after
a timeout); and fetch the server's final map (or, when it no longer answers, read its store).
The children ignore the terminal's Ctrl-C (``swarm.child_command``): the runner stops them, in
order (:mod:`swarm.mission.interrupts`).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from swarm.child_command import sigint_blocked, started_by_runner_environment, swarm_argv
from swarm.map.coverage_map import CoverageMap
from swarm.mission.role_failure import RoleError
from swarm.mission.team_monitor import TeamMonitor
from swarm.protocol.map_client import MapClient, MapQueryError, MapServerUnavailable
from swarm.protocol.sharded_client import ShardedMapClient

#: Every role process this process started, so that a second Ctrl-C can kill what is left.
_STARTED: list[subprocess.Popen] = []


def start_role(args: list[str], log_path: Path) -> subprocess.Popen:
    """Start ``swarm ARGS...`` as a child process, its output (stdout and stderr) in ``log_path``.

    The child ignores the terminal's SIGINT (it is started with SIGINT blocked until it
    ignores it): the runner stops it with SIGTERM (:func:`stop_roles`)."""
    log = open(log_path, "w")  # noqa: SIM115 (kept open for the child's lifetime)
    with sigint_blocked():
        child = subprocess.Popen(
            swarm_argv(*args),
            stdout=log,
            stderr=subprocess.STDOUT,
            env=started_by_runner_environment(PYTHONUNBUFFERED="1"),
        )
    child.log_path = log_path  # for why_it_exited
    _STARTED.append(child)
    return child


def started_count() -> int:
    """How many role processes this process has started so far (a mark for :func:`started_since`)."""
    return len(_STARTED)


def started_since(mark: int) -> list[subprocess.Popen]:
    """The role processes started after ``mark`` (:func:`started_count`): a run's own, also those
    an interrupt cut off before the run had kept them."""
    return list(_STARTED[mark:])


def kill_started_roles(reap_s: float = 0.5) -> int:
    """SIGKILL every role process this process started that still runs, and reap them (at most
    ``reap_s`` s); returns how many were killed."""
    running = [child for child in _STARTED if child.poll() is None]
    for child in running:
        child.kill()
    wait_for_roles(running, reap_s)
    return len(running)


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
    terminate_roles(procs)
    if not wait_for_roles(procs, timeout):
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def terminate_roles(procs: list[subprocess.Popen], yield_cpu: bool = False) -> None:
    """SIGTERM each running child (each stops in order: an agent flushes, the server compacts).
    ``yield_cpu``: also lower their priority to the least (nice 19), so that their stopping does
    not slow down this process (an interrupted runner writing its run folder on 2 cores)."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            if yield_cpu:
                try:
                    os.setpriority(os.PRIO_PROCESS, p.pid, 19)
                except (OSError, AttributeError):  # gone meanwhile, or no setpriority (not POSIX)
                    pass


def wait_for_roles(procs: list[subprocess.Popen], timeout: float) -> bool:
    """Wait up to ``timeout`` s in total for the children to exit; whether they all did."""
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.wait(timeout=max(0.05, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            return False
    return True


def wait_for_flush(agents: list[subprocess.Popen], monitor: TeamMonitor, timeout: float) -> None:
    """After SIGTERM to the agents: wait until they have all exited, or until no delta has come
    for 0.3 s after the first 0.5 s (an agent's shutdown flush goes out within a frame of the
    signal, and its process may take a second more to end), at most ``timeout`` s."""
    start = time.monotonic()
    seen, since = monitor.applied, start
    while (now := time.monotonic()) - start < timeout:
        if all(a.poll() is not None for a in agents):
            return
        if monitor.applied != seen:
            seen, since = monitor.applied, now
        elif now - start >= 0.5 and now - since >= 0.3:
            return
        time.sleep(0.05)


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


def final_server_map(
    client: MapClient | ShardedMapClient, monitor: TeamMonitor, timeout: float = 20.0
) -> CoverageMap | None:
    """The server's map once it has applied every delta the monitor saw, asking again until
    ``timeout`` s have passed; None then, and one line on stderr says why."""
    deadline = time.monotonic() + timeout
    expected = monitor.applied
    why = "it did not catch up with the monitor's deltas"
    while time.monotonic() < deadline:
        try:
            stats = client.stats()
            if int(stats.get("deltas_applied", 0)) >= expected:
                snap = client.team_snapshot()  # a sharded client's: the slabs side by side
                return CoverageMap(snap.grid, monitor.cmap.sensor, snap.lam, snap.eta)
            applied = int(stats.get("deltas_applied", 0))
            why = f"it applied {applied:,} of the {expected:,} deltas the monitor saw"
        except (MapServerUnavailable, MapQueryError) as exc:
            why = str(exc)
        time.sleep(0.3)
    print(f"runner: no final map from the map server within {timeout:g} s: {why}", file=sys.stderr)
    return None
