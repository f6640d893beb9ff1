"""Zenoh helpers: sessions on explicit endpoints, mission key expressions, reliable publishers.

Processes meet through explicit endpoints (the map server listens on
``tcp/127.0.0.1:7447`` by default, the others connect to it); multicast scouting is off
unless asked for, so tests and parallel runs do not find each other by accident. Deltas
and commands use reliable delivery with congestion control BLOCK: a full queue makes the
publisher wait instead of dropping the message.

A Zenoh configuration file (JSON5, ``--zenoh-config FILE`` or the ``ZENOH_CONFIG``
environment variable) carries what the command line does not: TLS certificates, access
control, timeouts (``swarm security init`` writes one per identity; docs/security.md).
Endpoints given on the command line replace the file's.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import socket
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import zenoh

from swarm.protocol.message_size import PATTERN_ROBOTS, bound_received_messages
from swarm.protocol.transport_limits import apply_team_limits, max_sessions_for, with_handshake_timeout

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: The sessions a router other than the map server keeps (swarm sim's runner): a team's worth.
DEFAULT_MAX_SESSIONS = max_sessions_for(PATTERN_ROBOTS)
ROOT = "swarm"
CONFIG_ENV = "ZENOH_CONFIG"
# TLS options naming files: a relative path in a config file is relative to that file
_TLS_FILES = (
    "root_ca_certificate",
    "listen_private_key",
    "listen_certificate",
    "connect_private_key",
    "connect_certificate",
)


def key(mission: str, *parts: str) -> str:
    """Key expression ``swarm/<mission>/<parts...>``; parts may hold '/' but no wildcards."""
    for text in (mission, *parts):
        text = str(text)
        if not text or any(c in "*$?#" for c in text) or text.startswith("/") or "//" in text:
            raise ValueError(f"bad key part {text!r}")
    return "/".join([ROOT, str(mission), *(str(p) for p in parts)])


def key_pattern(mission: str, *parts: str) -> str:
    """Like ``key`` but parts may be Zenoh wildcards (``*``, ``**``), for subscribers."""
    return "/".join([ROOT, str(mission), *(str(p) for p in parts)])


def make_config(
    listen: Iterable[str] = (),
    connect: Iterable[str] = (),
    *,
    multicast_scouting: bool = False,
    mode: str = "peer",
    base: zenoh.Config | None = None,
) -> zenoh.Config:
    """A Zenoh config with explicit listen/connect endpoints; multicast scouting off by default.

    With ``base`` (a config read from a file) the endpoints and mode are written over it and
    its scouting setting is kept.
    """
    conf = base if base is not None else zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    if base is None:
        conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return conf


def config_path(config_file: str | Path | None = None) -> Path | None:
    """The Zenoh config file to use: ``config_file``, else ``$ZENOH_CONFIG``, else None."""
    chosen = config_file if config_file else os.environ.get(CONFIG_ENV) or None
    return Path(chosen) if chosen else None


def load_config(path: str | Path) -> zenoh.Config:
    """Read a Zenoh JSON5 config file; relative TLS file paths are taken from the file's folder.

    Raises ``ValueError`` naming the file (and the field, for a missing certificate or key).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such Zenoh config file")
    try:
        conf = zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise ValueError(f"{path}: not a valid Zenoh config: {exc}") from exc
    for option in _TLS_FILES:
        field = f"transport/link/tls/{option}"
        value = json.loads(conf.get_json(field))
        if not value:
            continue
        target = Path(value) if Path(value).is_absolute() else (path.parent / value)
        if not target.is_file():
            raise ValueError(f"{path}: {field}: no such file {target}")
        conf.insert_json5(field, json.dumps(str(target.resolve())))
    return conf


def _endpoints(conf: zenoh.Config, which: str, mode: str) -> list[str]:
    """A config's ``listen``/``connect`` endpoints (a list, or a per-mode map)."""
    value = json.loads(conf.get_json(f"{which}/endpoints"))
    if isinstance(value, dict):
        value = value.get(mode, [])
    return [str(v) for v in value or []]


def session_config(
    listen: Iterable[str] | None = None,
    connect: Iterable[str] | None = None,
    *,
    config_file: str | Path | None = None,
    multicast_scouting: bool = False,
    max_message_bytes: int | None = None,
    max_sessions: int = DEFAULT_MAX_SESSIONS,
    timestamping: bool = False,
) -> tuple[zenoh.Config, list[str], list[str]]:
    """The config a role opens its session with, and the effective listen/connect endpoints.

    Endpoints given here win over the file's (``config_file`` or ``$ZENOH_CONFIG``); with
    neither, the session connects to ``DEFAULT_ENDPOINT``. A session that listens is a
    router, one that only connects a client. ``max_message_bytes``: the largest message the
    session takes from a link (``swarm.protocol.message_size``; a file's own value wins).
    Every session gets the team's transport limits (``swarm.protocol.transport_limits``; a
    file's own values win), ``max_sessions`` among them.
    ``timestamping``: stamp every sample with the session's clock, whatever its mode (a ROS 2
    node's latched topics need it: Zenoh's advanced publishers order their cache by it).
    """
    listen = list(listen or [])
    connect = list(connect or [])
    path = config_path(config_file)
    base = load_config(path) if path is not None else None
    if base is not None:
        file_mode = json.loads(base.get_json("mode"))
        listen = listen or (_endpoints(base, "listen", file_mode) if file_mode == "router" else [])
        connect = connect or _endpoints(base, "connect", file_mode)
    if not listen and not connect:
        connect = [DEFAULT_ENDPOINT]
    mode = "router" if listen else "client"
    listen_conf = [with_handshake_timeout(e) for e in listen]
    conf = make_config(listen_conf, connect, multicast_scouting=multicast_scouting, mode=mode, base=base)
    apply_team_limits(conf, max_sessions)
    if max_message_bytes is not None:
        bound_received_messages(conf, max_message_bytes)
    if timestamping:
        conf.insert_json5("timestamping/enabled", "true")
    return conf, listen, connect


def open_session(
    listen: Iterable[str] | None = None,
    connect: Iterable[str] | None = None,
    *,
    multicast_scouting: bool = False,
    wait_s: float = 30.0,
    config_file: str | Path | None = None,
    max_message_bytes: int | None = None,
    max_sessions: int = DEFAULT_MAX_SESSIONS,
    timestamping: bool = False,
) -> zenoh.Session:
    """Open a Zenoh session; with neither ``listen`` nor ``connect`` it connects to the default.

    A session that listens is a Zenoh *router*: it forwards messages between the sessions
    connected to it (the map server, or the mission runner inside ``swarm sim``). A session
    that only connects is a *client* of such a router; it tries for ``wait_s`` seconds, so a
    process may start before its router. A zenohd router between sites fits in unchanged.
    ``config_file`` (else ``$ZENOH_CONFIG``) is a Zenoh JSON5 config: TLS, access control;
    its endpoints are used when none are given here. Raises ``ValueError`` for a bad config
    file, ``zenoh.ZError`` when it cannot listen, and ``ConnectionError`` when no router
    accepts the connection in time (for TLS: a wrong certificate looks the same from this side).
    ``max_message_bytes`` bounds the messages it receives, ``max_sessions`` the sessions it
    keeps as a router, ``timestamping`` stamps every sample (``session_config``).
    """
    options = {
        "multicast_scouting": multicast_scouting,
        "max_message_bytes": max_message_bytes,
        "max_sessions": max_sessions,
        "timestamping": timestamping,
    }
    conf, listen, connect = session_config(listen, connect, config_file=config_file, **options)
    if listen:
        return zenoh.open(conf)  # a busy port raises zenoh.ZError (the CLI prints it as one line)
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            if time.monotonic() >= deadline:
                raise ConnectionError(
                    f"no Zenoh router answered at {', '.join(connect)} within {wait_s:g} s "
                    "(start the map server or the simulator first, or check --connect; "
                    "over TLS, check the certificates in the --zenoh-config file)"
                ) from exc
            time.sleep(0.5)
            conf = session_config(listen, connect, config_file=config_file, **options)[0]


def add_client_arguments(parser: argparse.ArgumentParser) -> None:
    """``--connect``, ``--listen`` and ``--zenoh-config`` of a role that joins a router (agent,
    coordinator): connect to the router's endpoints, optionally listen as well."""
    parser.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (default tcp/127.0.0.1:7447); repeatable",
    )
    parser.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on as well; repeatable",
    )
    add_zenoh_config_argument(parser)


def add_zenoh_config_argument(parser: argparse.ArgumentParser) -> None:
    """``--zenoh-config FILE``, the same for every command that opens a Zenoh session."""
    parser.add_argument(
        "--zenoh-config",
        metavar="FILE",
        type=Path,
        help=f"Zenoh config (JSON5): TLS certificates, access control (swarm security init writes one "
        f"per identity; docs/security.md). Default: ${CONFIG_ENV} if set. --listen/--connect win "
        "over the file's endpoints",
    )


def reliable_publisher(session: zenoh.Session, key_expr: str) -> zenoh.Publisher:
    """A publisher with reliable delivery and congestion control BLOCK (deltas, commands)."""
    return session.declare_publisher(
        key_expr,
        congestion_control=zenoh.CongestionControl.BLOCK,
        reliability=zenoh.Reliability.RELIABLE,
    )


def dropping_publisher(session: zenoh.Session, key_expr: str) -> zenoh.Publisher:
    """A publisher with reliable delivery and congestion control DROP: a link whose queue is full
    loses the sample instead of making ``put`` wait (the map server's ``merged``, whose
    subscribers catch up from ``map/snapshot``)."""
    return session.declare_publisher(
        key_expr,
        congestion_control=zenoh.CongestionControl.DROP,
        reliability=zenoh.Reliability.RELIABLE,
    )


def wait_for_subscribers(publishers: Iterable[zenoh.Publisher], timeout: float) -> bool:
    """Wait until every publisher has a matching subscriber; False on timeout."""
    publishers = list(publishers)
    deadline = time.monotonic() + timeout
    while True:
        if all(has_subscribers(p) for p in publishers):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)


def has_subscribers(publisher: zenoh.Publisher) -> bool:
    """Whether some subscriber matches the publisher's key expression right now."""
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


def subscribe_queue(
    session: zenoh.Session, key_expr: str, maxsize: int = 0
) -> tuple[zenoh.Subscriber, queue.Queue]:
    """Subscribe and collect ``(key, payload bytes)`` in a thread-safe queue."""
    inbox: queue.Queue = queue.Queue(maxsize)

    def on_sample(sample: zenoh.Sample) -> None:
        inbox.put((str(sample.key_expr), sample.payload.to_bytes()))

    return session.declare_subscriber(key_expr, on_sample), inbox


def subscribe(
    session: zenoh.Session, key_expr: str, callback: Callable[[str, bytes], None]
) -> zenoh.Subscriber:
    """Subscribe with a callback taking ``(key, payload bytes)``."""

    def on_sample(sample: zenoh.Sample) -> None:
        callback(str(sample.key_expr), sample.payload.to_bytes())

    return session.declare_subscriber(key_expr, on_sample)


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago (for tests and local runs)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def tcp_endpoint(port: int, host: str = "127.0.0.1") -> str:
    return f"tcp/{host}:{port}"


def describe_connection(listen: list[str] | None, connect: list[str] | None, wait_s: float = 30.0) -> str:
    """What a role says before opening its Zenoh session: where it listens or connects, and the wait."""
    listen, connect = list(listen or []), list(connect or [])
    if listen:
        also = f", also connecting to {', '.join(connect)}" if connect else ""
        return f"listening on {', '.join(listen)}{also}"
    where = ", ".join(connect or [DEFAULT_ENDPOINT])
    return (
        f"connecting to {where}: waiting up to {wait_s:g} s for a Zenoh router there "
        "(swarm server, or the runner of swarm sim)"
    )


#: The most servers a map service may have (``map_service.shards``, docs/sharding.md)
MAX_SHARDS = 64


def shard_mission(mission: str, shard: int, shards: int) -> str:
    """The key prefix of map server shard ``shard`` of ``shards``: the mission's own name when
    the map service is one server, else ``<mission>/shard/<k>`` (docs/sharding.md). Its
    deltas, merged stream and map queries are under ``swarm/<that>/...``."""
    if not 0 <= shard < shards:
        raise ValueError(f"no shard {shard} of {shards}")
    return mission if shards == 1 else f"{mission}/shard/{shard}"
