"""A team member turned stranger on the secured bus (mutual TLS, the rules `swarm security init`
writes): robot r1's agent puts on every key of the mission that is not its own and declares the
server's and coordinator's queryables. Nothing of it reaches another member; its own key does."""

from __future__ import annotations

import queue
import time

import pytest
import zenoh

from swarm.protocol import bus
from swarm.protocol.wire import Pose, Status
from swarm.security.team_setup import init_team
from tests.test_security import one_delta, secure_server, session_as
from tests.test_server_merge import wait_until

MISSION = "srvtest"


@pytest.fixture(scope="module")
def team(tmp_path_factory):
    return init_team(MISSION, ["r1", "r2"], tmp_path_factory.mktemp("team"))


def test_an_agent_can_put_only_on_its_own_keys(team, tmp_path):
    others = {
        "merged": one_delta("r2"),
        "delta/r2": one_delta("r2"),
        "delta/prior": one_delta("prior"),
        "robot/r2/status": b"forged",
        "robot/r2/cmd": b"forged",
        "robot/r1/frame": b"forged",  # only source-r1 or the world may
        "sim/truth": b"forged",
        "coord/assign": b"forged",
    }
    with secure_server(team, tmp_path / "store") as (server, endpoint):
        with session_as(team, "agent-r1", endpoint) as r1, session_as(team, "tool", endpoint) as watcher:
            seen: queue.Queue = queue.Queue()
            subscriber = watcher.declare_subscriber(
                bus.key_pattern(MISSION, "**"), lambda s: seen.put(str(s.key_expr))
            )
            time.sleep(0.3)
            forged_stats = r1.declare_queryable(
                bus.key(MISSION, "map", "stats"), lambda q: q.reply(q.key_expr, b"{}")
            )
            for key, payload in others.items():
                r1.put(bus.key(MISSION, *key.split("/")), payload)
            own = Status("r1", 0.0, Pose((1.0, 1.0, 0.0)), None, "drive", 0)
            r1.put(bus.key(MISSION, "robot", "r1", "status"), own.encode())  # after the others, same link
            wait_until(lambda: not seen.empty(), 10.0, "r1's own status")
            time.sleep(0.3)
            keys = [seen.get_nowait() for _ in range(seen.qsize())]
            replies = list(
                watcher.get(bus.key(MISSION, "map", "stats"), target=zenoh.QueryTarget.ALL, timeout=3.0)
            )
            forged_stats.undeclare()
            subscriber.undeclare()
    assert keys == [bus.key(MISSION, "robot", "r1", "status")], keys
    assert len(replies) == 1 and replies[0].ok.payload.to_bytes() != b"{}"
    assert server.stats()["deltas_applied"] == 0
