"""The ``swarm server`` process: a :class:`~map_server.server.MapServer` on a listening Zenoh
session until SIGTERM/SIGINT; SIGHUP quarantines the robots listed in ``<store>/quarantine``;
it announces the end of the mission on ``mission/done`` (:mod:`map_server.mission_end`). Of a
sharded map service (docs/sharding.md) it serves one shard's slab; shard 0 alone announces the end,
from the team's entropy summed over the shards (:mod:`map_server.shard_peers`)."""

from __future__ import annotations

import logging
import resource
import signal
import threading
from pathlib import Path

import zenoh

from map_server.mission_end import MissionEnd
from map_server.options import ServerOptions, message_limit_for
from map_server.server import MapServer
from map_server.shard_peers import ShardPeers
from map_server.shard_role import ShardRole
from swarm.child_command import stop_signals
from swarm.config import ConfigError, Mission
from swarm.protocol import bus
from swarm.protocol.transport_limits import max_sessions_for

log = logging.getLogger("swarm.server")

QUARANTINE_FILE = "quarantine"


def quarantine_list(path: Path) -> list[str]:
    """The robot ids of a quarantine file: one a line, ``#`` starts a comment; [] when absent."""
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        return []
    except OSError as exc:
        log.error("cannot read %s: %s", path, exc)
        return []
    return [r for r in (line.split("#", 1)[0].strip() for line in lines) if r]


def raise_open_files_limit() -> int:
    """Raise this process's soft limit of open files to its hard limit (every idle connection a
    stranger holds open costs the router one; docs/security.md, "Transport limits"); returns it."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
        return hard
    return soft


def server_session(
    server: MapServer,
    mission: Mission,
    listen: list[str],
    connect: list[str] | None = None,
    zenoh_config: Path | None = None,
) -> zenoh.Session:
    """The server's Zenoh session (the mission's router), which takes no message over
    :func:`~map_server.options.message_limit_for` from a link (docs/protocol.md, "Message sizes")."""
    limit = message_limit_for(mission, server.options, server.max_payload)
    sessions = max_sessions_for(len(mission.robot_ids))
    session = bus.open_session(
        listen=listen,
        connect=connect or [],
        config_file=zenoh_config,
        max_message_bytes=limit,
        max_sessions=sessions,
    )
    log.info(
        "Zenoh drops a received message over %s bytes (transport/link/rx/max_message_size; "
        "a --zenoh-config file that sets it wins)",
        f"{limit:,}",
    )
    return session


def mission_end(
    session: zenoh.Session, server: MapServer, mission: Mission, role: ShardRole | None = None
) -> tuple[MissionEnd | None, ShardPeers | None]:
    """The server's :class:`MissionEnd` (None on a shard other than 0: it never announces) and,
    on shard 0 of a sharded service, the :class:`ShardPeers` whose team entropy it compares
    with H_th. H_th is the mission's (a threshold that needs the simulator's ground truth is
    none here: then only "nothing left" ends the mission). ``role``: the server's own."""
    role = role or server.role
    if not role.decides_end:
        log.info("shard %d does not decide the end of the mission: shard 0 does", role.shard)
        return None, None
    try:
        server.threshold_bits = mission.threshold_bits()
    except ConfigError as exc:
        log.warning("no entropy threshold: %s; the mission ends when its robots have nothing left", exc)
    # unsharded: the server's own prefix (its --mission); sharded: the mission's, above the shards'
    prefix = role.mission if role.sharded else server.name
    log.info(
        "the mission ends when the team map's entropy%s is at most H_th = %s bits, or when every robot "
        "heard from has nothing left; then it is announced on %s",
        f" (summed over the {role.count} shards)" if role.sharded else "",
        "(none)" if server.threshold_bits is None else f"{server.threshold_bits:,.0f}",
        bus.key(prefix, "mission", "done"),
    )
    peers = ShardPeers(session, role, mission.sensor.model()) if role.sharded else None
    return MissionEnd(session, prefix, server.admission.robots, server.threshold_bits), peers


def serve(
    mission: Mission,
    listen: list[str],
    store_dir: Path,
    mission_name: str | None = None,
    options: ServerOptions | None = None,
    connect: list[str] | None = None,
    zenoh_config: Path | None = None,
    shard: int | None = 0,
) -> None:
    """Run the server until SIGTERM/SIGINT: recover the store, listen, merge; compact on exit.
    SIGHUP quarantines the robots listed in ``<store>/quarantine`` (one id a line).
    ``zenoh_config``: a Zenoh JSON5 config file (TLS, access control); ``listen``/``connect``
    win over its endpoints (``swarm.protocol.bus.open_session``). ``shard``: the slab of the
    mission's ``map_service`` served, under ``<mission_name>/shard/<k>`` when it has more than
    one (None: none given; ConfigError naming ``map_service.shards`` when it is out of range,
    or None for a sharded mission)."""
    role = ShardRole.of(mission, shard, mission_name)
    stop, reread = threading.Event(), threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in stop_signals()}
    previous[signal.SIGHUP] = signal.signal(signal.SIGHUP, lambda *_: reread.set())
    try:
        raise_open_files_limit()
        server = MapServer(mission, store_dir, role.prefix, options, shard=role.shard)
        if role.sharded:
            log.info("%s", role.describe())
        try:
            session = server_session(server, mission, listen, connect or [], zenoh_config)
        except BaseException:
            server.store.discard_new()  # a store this start created goes again
            raise
        end = peers = None
        try:
            server.start(session)
            _conf, endpoints, connects = bus.session_config(listen, connect or [], config_file=zenoh_config)
            source = "" if listen or connect else f" (from {bus.config_path(zenoh_config)})"
            if endpoints:
                log.info("listening on %s%s", ", ".join(e.split("#", 1)[0] for e in endpoints), source)
            else:  # a client of the mission's router (a secure shard k > 0: docs/sharding.md)
                log.info("connected to %s%s (listening on none)", ", ".join(connects), source)
            end, peers = mission_end(session, server, mission, role)
            if peers is not None:
                peers.start()
            while not stop.wait(0.5):
                if reread.is_set():
                    reread.clear()
                    for robot in quarantine_list(Path(store_dir) / QUARANTINE_FILE):
                        server.quarantine(robot)
                if end is None:
                    continue
                stats = server.stats()
                done = end.check(stats if peers is None else peers.team_stats(stats))
                if done is not None and server.mission_done is None:
                    server.mission_done = {"reason": done.reason, "t": done.t, "robots": done.robots_done}
            log.info("stopping: applying queued deltas and compacting the store")
        finally:
            if peers is not None:
                peers.close()
            if end is not None:
                end.close()
            server.stop()
            session.close()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
