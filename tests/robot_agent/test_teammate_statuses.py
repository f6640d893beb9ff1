"""An agent's view of its teammates' statuses over a real Zenoh session (loopback, explicit
endpoints): the newest status of each robot is noted; malformed ones, statuses on another
robot's key, statuses from the future and keys beyond the bound are not."""

from __future__ import annotations

import logging
import time

import pytest

from robot_agent.teammate_statuses import MAX_WAITING_KEYS, TeammateStatuses
from swarm.log_limit import LogLimiter
from swarm.navigation.teammates import MAX_TEAMMATES, Teammates
from swarm.protocol import bus
from swarm.protocol.wire import Pose, Status


def status(robot: str, t: float, x: float) -> bytes:
    return Status(robot, t, Pose((x, 1.0, 0.0)), None, "drive", 0).encode()


@pytest.mark.slow
def test_statuses_are_noted_newest_first_and_strangers_cannot_plant_robots():
    endpoint = bus.tcp_endpoint(bus.free_port())
    agent_session = bus.open_session(listen=[endpoint])
    stranger = bus.open_session(connect=[endpoint])
    try:
        statuses = TeammateStatuses(agent_session, "m", "r1", LogLimiter(logging.getLogger("test")))
        time.sleep(0.5)  # the subscription reaches the stranger's session
        key = lambda rid: bus.key("m", "robot", rid, "status")  # noqa: E731
        stranger.put(key("r2"), status("r2", 9.0, 2.0))
        stranger.put(key("r2"), status("r2", 10.0, 3.0))  # newer: replaces the one before
        stranger.put(key("r3"), status("r2", 10.0, 5.0))  # names r2 on r3's key
        stranger.put(key("r4"), b"\x00not msgpack")
        stranger.put(key("r5"), status("r5", 1e12, 4.0))  # from the future
        for k in range(MAX_WAITING_KEYS + 10):
            stranger.put(key(f"x{k}"), status(f"x{k}", 10.0, 0.0))
        deadline = time.monotonic() + 10.0
        while statuses.rejected < 10 and time.monotonic() < deadline:
            time.sleep(0.05)
        mates = Teammates("r1", robot_radius=0.18, max_speed=0.5)
        kept = statuses.apply(mates, now=10.0)
        assert mates.latest["r2"].xy == (3.0, 1.0)
        assert "r3" not in mates.latest and "r4" not in mates.latest and "r5" not in mates.latest
        # r2, then the invented ids that found room among the waiting keys, up to the book's bound
        assert kept == min(MAX_TEAMMATES, 1 + MAX_WAITING_KEYS - 4) == len(mates.latest)
        assert statuses.rejected >= 10 + 2  # beyond the bound; r3's and r4's
        assert statuses.apply(mates, now=10.5) == 0  # nothing new since
        statuses.undeclare()
    finally:
        stranger.close()
        agent_session.close()
