"""A secured team on loopback Zenoh (mutual TLS, the access rules of swarm security init): sessions
as a member, a running secured server, one delta."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import zenoh

from map_server.server import MapServer
from swarm.protocol import bus
from swarm.protocol.wire import DeltaMessage
from swarm.security.team_setup import init_team
from tests.support.map_server_mission import EPOCH, small_mission

ROBOTS = ["r1", "r2", "r3"]


@pytest.fixture(scope="module")
def team(tmp_path_factory):
    return init_team("srvtest", ROBOTS, tmp_path_factory.mktemp("team"))


@contextmanager
def secure_server(team, store: Path) -> Iterator[tuple[MapServer, str]]:
    """A map server in this process: the mission's router on a loopback TLS endpoint."""
    endpoint = f"tls/127.0.0.1:{bus.free_port()}"
    server = MapServer(small_mission(), store)
    session = bus.open_session(listen=[endpoint], config_file=team.configs["server"])
    server.start(session)
    try:
        yield server, endpoint
    finally:
        server.stop()
        session.close()


@contextmanager
def session_as(team, identity: str, endpoint: str) -> Iterator[zenoh.Session]:
    session = bus.open_session(connect=[endpoint], config_file=team.configs[identity], wait_s=5.0)
    try:
        yield session
    finally:
        session.close()


def one_delta(robot: str, seq: int = 1) -> bytes:
    grid = small_mission().workspace.grid()
    return DeltaMessage(
        robot,
        EPOCH,
        seq,
        1.0,
        grid,
        np.array([5, 6], np.int64),
        np.ones(2, np.float32),
        np.ones(2, np.float32),
    ).encode()
