"""A secured team on loopback Zenoh (mutual TLS, the access rules of swarm security init): sessions
as a member, a running secured server (or the servers of a sharded one), one delta."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np
import pytest
import zenoh

from map_server.server import MapServer
from swarm.protocol import bus
from swarm.protocol.wire import DeltaMessage
from swarm.security.access_rules import shard_server_name
from swarm.security.team_setup import init_team
from tests.support.map_server_mission import EPOCH, small_mission
from tests.support.shard_servers import sharded_mission

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


@contextmanager
def secure_shards(team, store: Path, shards: int = 2) -> Iterator[tuple[list[MapServer], str]]:
    """The map servers of a sharded ``srvtest`` in this process (stores ``store/shard-<k>``):
    shard 0 on the mission's router (``server``'s config, a loopback TLS endpoint), each shard
    k > 0 on a session of its own connected to it with ``server-shard-<k>``'s certificate, as
    ``swarm sim --secure`` runs them. ``team``: ``init_team(..., shards=shards)``."""
    mission = sharded_mission(shards)
    endpoint = f"tls/127.0.0.1:{bus.free_port()}"
    with ExitStack() as stack:
        router = bus.open_session(listen=[endpoint], config_file=team.configs["server"])
        stack.callback(router.close)
        servers = []
        for k in range(shards):
            session = router
            if k > 0:
                config = team.configs[shard_server_name(k)]
                session = bus.open_session(connect=[endpoint], config_file=config, wait_s=5.0)
                stack.callback(session.close)
            server = MapServer(mission, store / f"shard-{k}", shard=k)
            server.start(session)
            stack.callback(server.stop)
            servers.append(server)
        yield servers, endpoint


def slab_delta(robot: str, shard: int, shards: int = 2, seq: int = 1) -> bytes:
    """A delta of ``robot`` on shard ``shard``'s slab of ``sharded_mission(shards)`` (two voxels)."""
    grid = sharded_mission(shards).shard_layout().grid_of(shard)
    idx = np.array([5, 6], np.int64)
    return DeltaMessage(
        robot, EPOCH, seq, 1.0, grid, idx, np.ones(2, np.float32), np.ones(2, np.float32)
    ).encode()
