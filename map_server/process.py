"""The ``swarm server`` process: a :class:`~map_server.server.MapServer` on a listening Zenoh
session until SIGTERM/SIGINT; SIGHUP quarantines the robots listed in ``<store>/quarantine``."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path

import zenoh

from map_server.options import ServerOptions, message_limit_for
from map_server.server import MapServer
from swarm.child_command import stop_signals
from swarm.config import Mission
from swarm.protocol import bus

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
    session = bus.open_session(
        listen=listen, connect=connect or [], config_file=zenoh_config, max_message_bytes=limit
    )
    log.info(
        "Zenoh drops a received message over %s bytes (transport/link/rx/max_message_size; "
        "a --zenoh-config file that sets it wins)",
        f"{limit:,}",
    )
    return session


def serve(
    mission: Mission,
    listen: list[str],
    store_dir: Path,
    mission_name: str | None = None,
    options: ServerOptions | None = None,
    connect: list[str] | None = None,
    zenoh_config: Path | None = None,
) -> None:
    """Run the server until SIGTERM/SIGINT: recover the store, listen, merge; compact on exit.
    SIGHUP quarantines the robots listed in ``<store>/quarantine`` (one id a line).
    ``zenoh_config``: a Zenoh JSON5 config file (TLS, access control); ``listen``/``connect``
    win over its endpoints (``swarm.protocol.bus.open_session``)."""
    stop, reread = threading.Event(), threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in stop_signals()}
    previous[signal.SIGHUP] = signal.signal(signal.SIGHUP, lambda *_: reread.set())
    try:
        server = MapServer(mission, store_dir, mission_name, options)
        try:
            session = server_session(server, mission, listen, connect or [], zenoh_config)
        except BaseException:
            server.store.close()
            raise
        try:
            server.start(session)
            _conf, endpoints, _ = bus.session_config(listen, connect or [], config_file=zenoh_config)
            source = "" if listen else f" (from {bus.config_path(zenoh_config)})"
            log.info("listening on %s%s", ", ".join(endpoints), source)
            while not stop.wait(0.5):
                if reread.is_set():
                    reread.clear()
                    for robot in quarantine_list(Path(store_dir) / QUARANTINE_FILE):
                        server.quarantine(robot)
            log.info("stopping: applying queued deltas and compacting the store")
        finally:
            server.stop()
            session.close()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
