"""A team member turned stranger on the secured bus (mutual TLS, the rules `swarm security init`
writes): robot r1's agent puts on every key of the mission that is not its own and declares the
server's and coordinator's queryables. Nothing of it reaches another member; its own key does."""

from __future__ import annotations

import queue
import time

import pytest
import zenoh

from coordinator.role import Coordinator
from swarm.protocol import bus
from swarm.protocol.coord_client import ask_for_target, assign_key
from swarm.protocol.wire import AssignRequest, Pose, Status
from swarm.security.team_setup import init_team
from tests.support.map_server_mission import small_mission, wait_until
from tests.support.secure_team import one_delta, secure_server, session_as

MISSION = "srvtest"


@pytest.fixture(scope="module")
def team(tmp_path_factory):
    return init_team(MISSION, ["r1", "r2"], tmp_path_factory.mktemp("team"))


@pytest.mark.slow
def test_an_agent_can_put_only_on_its_own_keys(team, tmp_path):
    others = {
        "merged": one_delta("r2"),
        "delta/r2": one_delta("r2"),
        "delta/prior": one_delta("prior"),
        "robot/r2/status": b"forged",
        "robot/r2/cmd": b"forged",
        "robot/r1/frame": b"forged",  # only source-r1 or the world may
        "sim/truth": b"forged",
        "coord/assign/r1": b"forged",  # agent-r1 may only query its own assign key
        "coord/assign/r2": b"forged",
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


@pytest.mark.slow
def test_an_agent_can_ask_the_coordinator_only_as_its_own_robot(team, tmp_path):
    """Before, every agent queried one key, coord/assign, and the request's ``robot`` field said
    who asked: agent-r1 could ask as r2 (and supersede r2's waiting request) or as invented ids
    (and fill the coordinator's line). Now robot rid asks on coord/assign/<rid>: the rules let
    agent-r1 query coord/assign/r1 alone, and the coordinator refuses a request there naming r2."""
    here = Pose((0.5, 0.5, 0.4))
    with secure_server(team, tmp_path / "store") as (_server, endpoint):
        with (
            session_as(team, "coordinator", endpoint) as coord_session,
            session_as(team, "agent-r1", endpoint) as r1,
            session_as(team, "agent-r2", endpoint) as r2,
        ):
            coordinator = Coordinator(small_mission(), coord_session, mission_name=MISSION)
            coordinator.start()
            try:
                wait_until(
                    lambda: ask_for_target(r1, MISSION, "r1", here, timeout=1.0) is not None,
                    20.0,
                    "r1's answer on its own key",
                )
                before = coordinator.counts
                as_r2 = AssignRequest("r2", here).encode()
                for key in (
                    assign_key(MISSION, "r2"),
                    assign_key(MISSION, "r9"),  # an invented robot
                    bus.key_pattern(MISSION, "coord", "assign", "*"),
                    bus.key_pattern(MISSION, "coord", "**"),
                ):
                    replies = list(r1.get(key, payload=as_r2, timeout=1.0))
                    assert replies == [], f"{key}: {replies}"  # the router dropped the query
                replies = list(r1.get(assign_key(MISSION, "r1"), payload=as_r2, timeout=5.0))
                assert len(replies) == 1 and replies[0].ok is None
                error = replies[0].err.payload.to_bytes().decode()
                assert error == "coord/assign: assign request: robot 'r2' asked on the key of 'r1'"
                assert ask_for_target(r2, MISSION, "r2", Pose((2.5, 1.5, 0.4)), timeout=5.0) is not None
                counts = coordinator.counts
            finally:
                coordinator.stop()
    new = {k: counts[k] - before[k] for k in ("requests", "requests_rejected", "requests_robot_mismatch")}
    assert new == {"requests": 2, "requests_rejected": 1, "requests_robot_mismatch": 1}, new
    assert counts["requests_superseded"] == 0 and counts["requests_busy"] == 0
