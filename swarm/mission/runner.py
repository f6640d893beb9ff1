"""``swarm sim``: a whole mission on one machine, every role a separate process over Zenoh.

The runner writes the effective mission to the run folder and is the mission's Zenoh
router on a loopback endpoint. It starts the map server (``swarm server``, its store in
the run folder), the coordinator (``swarm coordinator``, unless coordination is off), the
simulated world (``swarm sim world``) and one ``swarm agent`` per robot, and watches the
mission as any monitor could (:class:`swarm.mission.team_monitor.TeamMonitor`): it keeps a
replica of the team map from ``delta/*`` (the entropy curve, bytes and overlap per robot),
trajectories from ``sim/truth`` and states from ``robot/*/status``. It stops at H_th (eq.
36), when every agent is done, or at the time limit; agents flush their outboxes, the
server's final map is fetched over ``map/snapshot``, and the run folder is written:
metrics.json, map.npz, server_map.npz, plots, the config used and every process's log.
``--view`` starts ``swarm view`` beside the roles; a view that cannot start (no display for
its window, no rerun) is one warning line and the mission goes on without it.

With ``secure`` (``swarm sim --secure``) the run folder gets a fresh team of certificates
(``security/``, as ``swarm security init`` writes it); the map server (shard 0 of a sharded
map service) is then the mission's router on a loopback TLS endpoint with the access-control
rules, every role (the other shards too) connects to it with its own certificate; the runner
watches (and loads a previous map) as ``operator``.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robot_agent.kernels import load_kernels
from swarm.config import Mission
from swarm.mission.interrupts import Interrupts
from swarm.mission.map_service import MapService
from swarm.mission.role_processes import (
    final_server_map,
    started_count,
    started_since,
    stop_roles,
    terminate_roles,
    wait_for_flush,
    wait_for_roles,
    wait_for_server,
    why_it_exited,
)
from swarm.mission.role_processes import start_role as start_role_process
from swarm.mission.team_monitor import TeamMonitor
from swarm.protocol import bus, coord_client
from swarm.protocol.mission_listener import MissionDoneListener
from swarm.security.access_rules import OPERATOR, TOOL, agent_name, shard_server_name

#: After an interrupt: seconds to wait for the agents' flush (their exit), then for the map
#: server's map; the roles still stopping get INTERRUPTED_STOP_S more (then SIGKILL) once the
#: run folder is written (``facts["stopping"]``), or at once when the map must come from the store.
INTERRUPTED_FLUSH_S = 1.5
INTERRUPTED_MAP_S = 2.0
INTERRUPTED_STOP_S = 3.0


@dataclass
class MissionOptions:
    out: Path
    strategy: str = "entropy"
    seed: int = 0
    max_time_s: float | None = None
    wall_limit_s: float = 3600.0
    quiet: bool = False
    coordination: str = "coordinator"  # or "none": each robot chooses alone on the shared map
    kill_coordinator_at_s: float | None = None  # fault injection: SIGKILL it at this sim time
    view: str | None = None  # "window": swarm view beside the mission; a path: its .rrd recording
    secure: bool = False  # mutual TLS and access control, one certificate per role
    ros2: bool = False  # every robot's frames and commands over ROS 2 (rmw_zenoh), docs/ros2.md


@dataclass(frozen=True)
class BusPlan:
    """Where each role meets the others: the runner's session, and each child's Zenoh arguments."""

    runner_listen: list[str]
    runner_connect: list[str]
    runner_config: Path | None
    server_args: list[str]
    configs: dict[str, Path]  # identity -> Zenoh config file (empty when not secure)

    def child_args(self, identity: str) -> list[str]:
        """``--connect`` and ``--zenoh-config`` of a role that is not the server."""
        endpoint = (self.runner_connect or self.runner_listen)[0]
        config = self.configs.get(identity)
        return ["--connect", endpoint, *(["--zenoh-config", str(config)] if config else [])]

    def server_bus_args(self, shard: int) -> list[str]:
        """The bus arguments of map server shard ``shard`` (0: the only one when unsharded).
        Open loopback: each server listens on a port of its own and connects to the runner.
        Secure: shard 0 is the TLS router (``server_args``); shard k > 0 connects to it with its
        own certificate ``server-shard-<k>``, whose rules allow it only its own shard's keys."""
        if shard == 0:
            return list(self.server_args)
        if self.configs:
            return self.child_args(shard_server_name(shard))
        connect = [a for e in self.runner_listen for a in ("--connect", e)]
        return ["--listen", bus.tcp_endpoint(bus.free_port()), *connect]


def plan_bus(mission: Mission, out: Path, secure: bool) -> BusPlan:
    """Open loopback: the runner is the router. Secure: the server is, over TLS with the rules."""
    if not secure:
        endpoint = bus.tcp_endpoint(bus.free_port())
        server_listen = bus.tcp_endpoint(bus.free_port())
        return BusPlan([endpoint], [], None, ["--listen", server_listen, "--connect", endpoint], {})
    from swarm.security.team_setup import init_team

    folder = out / "security"
    if folder.exists():
        shutil.rmtree(folder)  # a run folder is rewritten: a fresh CA per run
    shards = mission.shard_layout().count  # a sharded service: one identity per shard server
    team = init_team(mission.mission, list(mission.robot_ids), folder, shards=shards)
    endpoint = f"tls/127.0.0.1:{bus.free_port()}"
    server_args = ["--listen", endpoint, "--zenoh-config", str(team.configs["server"])]
    return BusPlan([], [endpoint], team.configs[OPERATOR], server_args, team.configs)


def run_mission(
    mission: Mission, options: MissionOptions, interrupts: Interrupts | None = None
) -> tuple[TeamMonitor, dict]:
    """Run ``mission`` with every role in its own process; returns the monitor and run facts.

    ``interrupts`` (the command's :class:`~swarm.mission.interrupts.Interrupts`): a first Ctrl-C
    or SIGTERM ends the run with reason ``interrupted``: the agents and the world are told to
    stop, the agents' flush gets :data:`INTERRUPTED_FLUSH_S` s, the map server's map
    :data:`INTERRUPTED_MAP_S` s (else it is read from the server's store once the server has
    stopped), and the facts are returned as for any other end, with the roles that are still
    stopping in ``facts["stopping"]``: the caller ends them with ``stop_roles(...,
    INTERRUPTED_STOP_S)`` once it has written the run folder. Interrupted while starting, the
    reason is ``interrupted while starting``."""
    out = options.out
    out.mkdir(parents=True, exist_ok=True)
    if options.max_time_s is not None:
        mission = mission.model_copy(
            update={"stop": mission.stop.model_copy(update={"max_time_s": options.max_time_s})}
        )
    config_path = out / "config.yaml"
    config_path.write_text(mission.to_yaml())
    threshold = mission.threshold_bits()
    # Compile the fusion and point kernels once here (a no-op load when Numba's cache is warm), so that
    # the agents load them from the cache instead of each compiling them at start.
    load_kernels(None if options.quiet else lambda line: print(line, flush=True), "runner")

    monitor = TeamMonitor(mission)
    name = mission.mission
    mark = started_count()  # this run's role processes are those started from here on

    def start_role(args: list[str], log_path: Path) -> subprocess.Popen:
        """A role process, started and kept in one piece (an interrupt waits for its end)."""
        with interrupts.deferred() if interrupts is not None else nullcontext():
            return start_role_process(args, log_path)

    plan = plan_bus(mission, out, options.secure)
    # one server, or one per shard of a sharded map service (swarm.mission.map_service)
    service = MapService(mission, out, config_path, plan.server_bus_args)
    store = service.store
    service.clear_stores()  # a run folder is rewritten: the server must not recover an old map
    server_cmds = service.commands()
    # open loopback: the runner is the mission's router; secure: the server is, so it starts first
    server = None if plan.runner_listen else start_role(server_cmds[0], service.log_of(0))
    try:
        session = bus.open_session(plan.runner_listen, plan.runner_connect, config_file=plan.runner_config)
    except BaseException:
        stop_roles([server] if server is not None else [])
        raise
    ending = MissionDoneListener(session, name, lambda _done: None)  # the map server's end, if it says
    subs = [
        *service.watch_deltas(session, monitor),
        bus.subscribe(session, bus.key_pattern(name, "sim", "truth"), monitor.on_truth),
        bus.subscribe(session, bus.key_pattern(name, "robot", "*", "status"), monitor.on_status),
    ]
    services: list[subprocess.Popen] = []
    world: subprocess.Popen | None = None
    agents: list[subprocess.Popen] = []
    server_map = None
    coordinator_stats = None
    at_stop = (monitor.team_entropy, 0)
    client = service.client(session, timeout=2.0)
    started = time.monotonic()
    reason = "starting"
    try:
        if server is None:
            server = start_role(server_cmds[0], service.log_of(0))
        services.append(server)
        services += [start_role(cmd, service.log_of(k)) for k, cmd in enumerate(server_cmds[1:], 1)]
        shards = list(services)
        coordinator = None
        if options.coordination != "none":
            coordinator_args = ["coordinator", "--config", str(config_path), *plan.child_args("coordinator")]
            coordinator = start_role(coordinator_args, out / "coordinator.log")
            services.append(coordinator)
        for k, process in enumerate(shards):
            wait_for_server(service.shard_client(session, k), process)
        if not options.quiet:  # docs/interop.md: the map tools work on a running mission too
            query = ["swarm map stats", *plan.child_args(TOOL), "--mission", name]
            print(
                f"runner: the map server is up; to query it while the mission runs: {' '.join(query)}",
                flush=True,
            )
        if mission.prior_map is not None:
            voxels = service.publish_prior(session, monitor)
            path = mission.prior_map_path()
            print(f"runner: started from the previous map {path}: {voxels:,} voxels known", flush=True)
        view = _start_view(options.view, plan, name, out, start_role)
        if view is not None:
            services.append(view)
        ros2 = ["--ros2"] if options.ros2 else []
        world_args = ["sim", "world", str(config_path), *plan.child_args("world"), *ros2]
        world = start_role(world_args, out / "world.log")
        coordination = "auto" if options.coordination != "none" else "none"
        ros2 += ["--ros2-use-sim-time"] if options.ros2 else []
        agents = [
            start_role(
                ["agent", "--id", rid, *plan.child_args(agent_name(rid)), "--config", str(config_path),
                 "--strategy", options.strategy, "--seed", str(options.seed), "--coordination", coordination,
             *ros2],
                out / f"agent-{rid}.log",
            )
            for rid in mission.robot_ids
        ]  # fmt: skip
        started = time.monotonic()
        reason = "running"
        last_print = last_wait_print = -math.inf
        while True:
            time.sleep(0.2)
            now = time.monotonic()
            h = monitor.team_entropy
            kill_at = options.kill_coordinator_at_s
            if coordinator is not None and kill_at is not None and monitor.sim_time >= kill_at:
                if coordinator.poll() is None:
                    coordinator.kill()
                    print(f"runner: killed the coordinator at sim t={monitor.sim_time:.1f} s", flush=True)
            if view is not None and view.poll() is not None:  # the view listens: the mission goes on
                if view.returncode != 0:
                    why = why_it_exited(view)
                    print(f"runner: warning: the view (--view) {why}; the mission goes on", file=sys.stderr)
                view = None
            if h <= threshold:
                reason = "threshold"
            elif monitor.states and all(monitor.states.get(r) == "done" for r in mission.robot_ids):
                reason = "agents done"
            elif ending.done is not None:  # the map server ended it (its H, or nothing left), first
                reason = "threshold" if ending.done.reason == "threshold" else "agents done"
            elif world.poll() is not None:
                reason = why_the_world_stopped(monitor, mission)
                if world.returncode != 0:  # it failed: say so, and the run folder's stop_reason does
                    why = why_it_exited(world)
                    reason = f"world failed: it {why}"
                    print(f"runner: warning: the simulated world {why}", file=sys.stderr)
            elif now - started > options.wall_limit_s:
                reason = "wall-clock limit"
            if not options.quiet and (now - last_print > 2.0 or reason != "running"):
                last_print = now
                if monitor.sim_time == 0.0 and reason == "running":  # the world waits for every agent
                    if now - last_wait_print < 10.0:  # this line every 10 s, not every 2
                        continue
                    last_wait_print = now
                    print(
                        f"[{now - started:6.1f} s] starting: the world waits for the agents of "
                        f"{', '.join(mission.robot_ids)} (each starts its process and loads its "
                        "kernels from Numba's cache, compiled by the runner)",
                        flush=True,
                    )
                    continue
                known = float(np.mean(monitor.cmap.known_mask()))
                states = " ".join(f"{r}:{monitor.states.get(r, '-')}" for r in mission.robot_ids)
                print(
                    f"[{now - started:6.1f} s] sim t={monitor.sim_time:7.1f} s  H={h:,.0f} bits "
                    f"(H_th {threshold:,.0f})  known {known:5.1%}  {states}",
                    flush=True,
                )
            if reason != "running":
                at_stop = (h, monitor.applied)  # what the last progress line showed
                break
    except KeyboardInterrupt:  # the first Ctrl-C or SIGTERM (swarm.mission.interrupts)
        reason = "interrupted" if reason == "running" else "interrupted while starting"
        at_stop = (monitor.team_entropy, monitor.applied)
    finally:
        interrupted = reason.startswith("interrupted")
        map_source = None
        stopping: list[subprocess.Popen] = []  # interrupted: roles told to stop, not waited for
        with interrupts.held() if interrupts is not None else nullcontext():
            if interrupted:  # the agents flush (through this router: it stays open) as the world stops
                # every role but the services: also one an interrupt cut off before it was kept
                kept = [p for p in (server, *services) if p is not None]
                stopping = [p for p in started_since(mark) if all(p is not s for s in kept)]
                terminate_roles(stopping, yield_cpu=True)
                wait_for_flush(agents, monitor, INTERRUPTED_FLUSH_S)
            else:
                stop_roles(agents)  # agents flush their pending deltas on SIGTERM
                stop_roles([world] if world is not None else [])
            if not reason.endswith("starting"):
                server_map = final_server_map(client, monitor, INTERRUPTED_MAP_S if interrupted else 20.0)
                map_source = None if server_map is None else "the map server"
                if options.coordination != "none":
                    timeout = 0.5 if interrupted else 2.0
                    coordinator_stats = coord_client.coordinator_stats(session, name, timeout)
            if interrupted:  # the server compacts its store as it stops, while the caller evaluates
                kept = [p for p in (server, *services) if p is not None]
                services = list({id(p): p for p in kept}.values())
                terminate_roles(services, yield_cpu=True)
                stopping += services
            else:
                stop_roles(services)
            if (
                server_map is None
                and reason == "interrupted"
                and wait_for_roles(services, INTERRUPTED_STOP_S)
            ):
                server_map = service.store_map(monitor)
                map_source = None if server_map is None else f"the map server's store {store}/"
            if not interrupted:  # whatever an error cut off before the run kept it
                stop_roles([p for p in started_since(mark) if p.poll() is None])
            for sub in subs:
                sub.undeclare()
            ending.close()
            session.close()
    facts = {
        "reason": reason,
        "wall_time_s": time.monotonic() - started,
        "threshold_bits": threshold,
        "server_map": server_map,
        "map_source": map_source,
        "signal": interrupts.first if interrupts is not None else None,
        "coordinator_stats": coordinator_stats,
        "stopping": stopping,
        "at_stop": {"entropy_bits": at_stop[0], "deltas": at_stop[1], "deltas_after_flush": monitor.applied},
        "exit_codes": {
            "world": world.returncode if world is not None else None,
            "server": services[0].returncode if services else None,
            **{r: a.returncode for r, a in zip(mission.robot_ids, agents, strict=False)},  # those started
        },
    }
    return monitor, facts


def why_the_world_stopped(monitor: TeamMonitor, mission: Mission) -> str:
    """The run's stop reason once the world has ended by itself (exit 0), from its last
    ``sim/truth`` message: "max time (T s simulated)" when the simulated clock reached
    ``stop.max_time_s`` (within 1.5 frame periods: the world may end before its last message is
    read), "every agent dead (...)" when no agent answered within ``sim.agent_timeout_s``,
    else "world stopped" (no truth message told which)."""
    if mission.robot_ids and set(mission.robot_ids) <= set(monitor.dead):
        return f"every agent dead ({', '.join(mission.robot_ids)}: none answered within sim.agent_timeout_s)"
    max_time = mission.stop.max_time_s
    if monitor.sim_time >= max_time - 1.5 * mission.sim.frame_period_s:
        return f"max time ({max_time:g} s simulated)"
    return "world stopped"


def _start_view(
    view: str | None, plan: BusPlan, mission: str, out: Path, start_role
) -> subprocess.Popen | None:
    """``swarm view`` beside the mission (``view``: "window", or the .rrd file to record), or None,
    started with ``start_role``.

    A window needs a display: without one (:func:`swarm.view.live.missing_display`) the view is
    not started and one warning line says what to do instead; the mission runs as without --view.
    """
    if view is None:
        return None
    from swarm.view.live import missing_display

    args = ["view", *plan.child_args(TOOL), "--mission", mission]
    if view != "window":
        args += ["--save", str(Path(view).resolve())]
    elif why := missing_display():
        print(
            f"runner: warning: --view: {why}; the mission goes on without the view: run without --view, "
            "or record it with --view RUN.rrd and open that with `rerun RUN.rrd` where there is a display "
            "(the run folder's top_view.png and map_3d.png show the final map)",
            file=sys.stderr,
            flush=True,
        )
        return None
    return start_role(args, out / "view.log")
