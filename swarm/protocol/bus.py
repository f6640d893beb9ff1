"""Zenoh helpers: sessions on explicit endpoints, mission key expressions, reliable publishers.

Processes meet through explicit endpoints (the map server listens on
``tcp/127.0.0.1:7447`` by default, the others connect to it); multicast scouting is off
unless asked for, so tests and parallel runs do not find each other by accident. Deltas
and commands use reliable delivery with congestion control BLOCK: a full queue makes the
publisher wait instead of dropping the message.
"""

from __future__ import annotations

import json
import queue
import socket
import time
from collections.abc import Callable, Iterable

import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ROOT = "swarm"


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
) -> zenoh.Config:
    """A Zenoh config with explicit listen/connect endpoints; multicast scouting off by default."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return conf


def open_session(
    listen: Iterable[str] | None = None,
    connect: Iterable[str] | None = None,
    *,
    multicast_scouting: bool = False,
    wait_s: float = 30.0,
) -> zenoh.Session:
    """Open a Zenoh session; with neither ``listen`` nor ``connect`` it connects to the default.

    A session that listens is a Zenoh *router*: it forwards messages between the sessions
    connected to it (the map server, or the mission runner inside ``swarm sim``). A session
    that only connects is a *client* of such a router; it tries for ``wait_s`` seconds, so a
    process may start before its router. A zenohd router between sites fits in unchanged.
    """
    listen = list(listen or [])
    connect = list(connect or [])
    if not listen and not connect:
        connect = [DEFAULT_ENDPOINT]
    if listen:
        return zenoh.open(make_config(listen, connect, multicast_scouting=multicast_scouting, mode="router"))
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return zenoh.open(make_config([], connect, multicast_scouting=multicast_scouting, mode="client"))
        except zenoh.ZError as exc:
            if time.monotonic() >= deadline:
                raise ConnectionError(
                    f"no Zenoh router answered at {', '.join(connect)} within {wait_s:g} s "
                    "(start the map server or the simulator first, or check --connect)"
                ) from exc
            time.sleep(0.5)


def reliable_publisher(session: zenoh.Session, key_expr: str) -> zenoh.Publisher:
    """A publisher with reliable delivery and congestion control BLOCK (deltas, commands)."""
    return session.declare_publisher(
        key_expr,
        congestion_control=zenoh.CongestionControl.BLOCK,
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
