"""An agent fed hostile frames (depth NaN, inf, negative, zero, 1e30, 3.4e38, subnormal; poses
1e19 m away or at 1.7e308, angles of 1e308 rad): it answers each with a command, its map
stays finite, and a frame with no usable depth adds nothing."""

from __future__ import annotations

import numpy as np
import pytest

from robot_agent.agent import Agent
from swarm.protocol import bus
from swarm.protocol.wire import Camera, Frame, Pose
from tests.support.map_server_mission import small_mission

POSE = Pose((0.5, 0.5, 0.3), (0.3, 0.0, 0.0))


@pytest.fixture(scope="module")
def agent():
    mission = small_mission()
    session = bus.open_session(listen=[bus.tcp_endpoint(bus.free_port())])
    try:
        yield Agent(mission, "r1", session, coordination=False)
    finally:
        session.close()


def test_hostile_depth_frames_leave_the_map_finite_and_unchanged(agent):
    rig = agent.mission.rig_for("r1")
    camera = Camera(rig.width, rig.height, 80.0, 80.0, rig.width / 2, rig.height / 2, 0.1)
    shape = (rig.height, rig.width)

    def frame(seq: int, pose: Pose, depth: float) -> bytes:
        return Frame("r1", seq, float(seq), pose, camera, depth=np.full(shape, depth, np.float32)).encode()

    assert agent.handle(frame(1, POSE, 1.5)) is not None  # an honest frame first
    before = agent.explorer.map.lam.copy(), agent.explorer.map.eta.copy()
    useless = [np.nan, np.inf, -np.inf, -1.0, 0.0, 1e30, 3.4e38, 1e-40]
    for seq, depth in enumerate(useless, start=2):
        assert agent.handle(frame(seq, POSE, depth)) is not None, depth
    np.testing.assert_array_equal(agent.explorer.map.lam, before[0])
    np.testing.assert_array_equal(agent.explorer.map.eta, before[1])
    far = [
        Pose((1e19, -1e19, 1e19)),
        Pose((1.7e308, 1.7e308, 0.3)),
        Pose((0.5, 0.5, 0.3), (1e308, -1e308, 1e300)),
    ]
    for seq, pose in enumerate(far, start=20):
        assert agent.handle(frame(seq, pose, 1.5)) is not None, pose
    lam, eta = agent.explorer.map.lam, agent.explorer.map.eta
    assert np.all(np.isfinite(lam)) and np.all(lam > 0) and np.all((eta >= 0) & (eta <= lam * 1.0001))
    assert np.isfinite(agent.explorer.map_entropy) and agent.rejected_frames == 0
