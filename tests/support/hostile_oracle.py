"""What a map server under attack must still hold: the map of the honest robots alone (oracle),
their stream, and a strict JSON reader for map/stats."""

from __future__ import annotations

import json

from map_server.team_map import MergedMap
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import (
    encode_all,
    robot_batches,
)


def strict_json(text: bytes) -> dict:
    """JSON as RFC 8259 has it: NaN and Infinity are not JSON."""

    def refuse(name: str):
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def oracle(mission, payloads: list[bytes]) -> MergedMap:
    """The map of exactly these valid deltas, merged without a server."""
    team = MergedMap(mission.workspace.grid(), mission.sensor.model())
    for p in payloads:
        msg = DeltaMessage.decode(p)
        if team.admit(msg):
            team.apply(msg)
    return team


def honest_stream(mission, robots=("r1", "r2", "r3"), per_robot: int = 4, seed: int = 0):
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    batches = robot_batches(grid, sensor, robots=len(robots), per_robot=per_robot, seed=seed)
    return encode_all(grid, batches)
