"""A Zenoh session for ROS 2 topics: the project's session config with timestamping on.

rmw_zenoh's TRANSIENT_LOCAL publishers are Zenoh advanced publishers with a cache
(``swarm.ros2.node``), and Zenoh refuses one on a session that does not timestamp its samples,
which a client session does not by default (Zenoh's ``timestamping/enabled``: router and peer
on, client off). Sessions that carry ROS 2 topics are opened here.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from pathlib import Path

import zenoh

from swarm.protocol import bus


def open_ros2_session(
    connect: Iterable[str] | None = None,
    listen: Iterable[str] | None = None,
    *,
    config_file: str | Path | None = None,
    wait_s: float = 30.0,
) -> zenoh.Session:
    """A session as ``swarm.protocol.bus.open_session`` opens it (endpoints, ``config_file``,
    multicast scouting off), timestamping its samples. Connecting, it tries for ``wait_s``
    seconds; raises ``ConnectionError`` naming the endpoints when no router accepts it,
    ``ValueError`` for a bad config file, ``zenoh.ZError`` when it cannot listen."""
    conf, listen, connect = _config(listen, connect, config_file)
    if listen:
        return zenoh.open(conf)
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            if time.monotonic() >= deadline:
                raise ConnectionError(
                    f"no Zenoh router answered at {', '.join(connect)} within {wait_s:g} s "
                    "(the robots' rmw_zenohd, or the mission's map server)"
                ) from exc
            time.sleep(0.5)
            conf = _config(listen, connect, config_file)[0]


def _config(listen, connect, config_file) -> tuple[zenoh.Config, list[str], list[str]]:
    conf, listen, connect = bus.session_config(listen, connect, config_file=config_file)
    conf.insert_json5("timestamping/enabled", "true")
    return conf, listen, connect
