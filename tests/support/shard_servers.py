"""Map servers of a sharded mission on one loopback router, in-process (docs/sharding.md)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import yaml

from map_server.server import MapServer
from swarm.config import Mission, mission_from_dict
from swarm.protocol import bus
from tests.support.map_server_mission import MISSION_YAML


def sharded_mission(shards: int = 2) -> Mission:
    """The small map-server test mission with ``map_service.shards``."""
    data = yaml.safe_load(MISSION_YAML)
    data["map_service"] = {"shards": shards}
    return mission_from_dict(data)


@contextmanager
def shard_servers(store: Path, shards: int = 2) -> Iterator[tuple[Mission, list[MapServer], object]]:
    """``(mission, servers, client session)``: one MapServer per shard (stores
    ``store/shard-<k>``) on one loopback router, and a client session connected to it."""
    mission = sharded_mission(shards)
    endpoint = bus.tcp_endpoint(bus.free_port())
    with ExitStack() as stack:
        router = bus.open_session(listen=[endpoint])
        stack.callback(router.close)
        servers = []
        for k in range(shards):
            server = MapServer(mission, store / f"shard-{k}", shard=k)
            server.start(router)
            stack.callback(server.stop)
            servers.append(server)
        client = bus.open_session(connect=[endpoint])
        stack.callback(client.close)
        yield mission, servers, client
