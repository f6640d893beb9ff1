"""An agent on a mission without start poses (real robots: no simulator places them) takes its
robot's pose from its frames: from the first frame on it maps around, plans from and reports
the pose the frame carries, wherever in the workspace that is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_agent.agent import Agent
from swarm.config import ConfigError, mission_from_dict
from swarm.protocol import bus
from swarm.protocol.wire import Camera, Frame, Pose, Status

#: the map-server tests' small workspace, its robots without ``start``
MISSION = {
    "mission": "nostart",
    "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [3.0, 2.0, 1.0], "voxel": 0.1},
    "robots": [{"id": "r1"}, {"id": "r2"}],
    "stop": {"entropy_threshold_bits": 1000.0},
}


@pytest.fixture(scope="module")
def session():
    session = bus.open_session(listen=[bus.tcp_endpoint(bus.free_port())])
    yield session
    session.close()


def frame(agent: Agent, seq: int, pose: Pose, depth: float = 0.8) -> Frame:
    rig = agent.mission.rig_for(agent.robot_id)
    camera = Camera(rig.width, rig.height, 80.0, 80.0, rig.width / 2, rig.height / 2, 0.1)
    return Frame(
        agent.robot_id,
        seq,
        0.5 * seq,
        pose,
        camera,
        depth=np.full((rig.height, rig.width), depth, np.float32),
    )


@pytest.mark.parametrize(
    "robot, pose, ahead",
    [
        ("r1", Pose((2.5, 1.5, 0.3), (math.pi, 0.0, 0.0)), -1),  # at the far end, facing -x
        ("r2", Pose((0.5, 0.5, 0.3), (0.0, 0.0, 0.0)), +1),  # at the near end, facing +x
    ],
)
def test_an_agent_without_a_start_pose_takes_it_from_its_first_frame(session, robot, pose, ahead):
    mission = mission_from_dict(MISSION)
    with pytest.raises(ConfigError, match=r"robots\[\d\]\.start: is required by the simulator"):
        mission.start_of(robot)  # nothing to fall back on: the pose can only come from the frames
    agent = Agent(mission, robot, session, coordination=False)
    status_sub, statuses = bus.subscribe_queue(session, bus.key("nostart", "robot", robot, "status"))
    try:
        before = agent.explorer.map.lam.copy()
        cmd = agent.handle(frame(agent, 1, pose).encode())
        assert cmd is not None and cmd.seq == 1
        # what it mapped lies in front of the frame's pose, within the frame's depth
        changed = np.flatnonzero(agent.explorer.map.lam.ravel() != before.ravel())
        assert changed.size > 0
        centres = agent.explorer.grid.centre(agent.explorer.grid.unflat(changed))
        x0 = pose.xyz[0]
        assert np.all(ahead * (centres[:, 0] - x0) > -0.2), (x0, centres[:, 0].min(), centres[:, 0].max())
        assert np.all(np.linalg.norm(centres[:, :2] - pose.xyz[:2], axis=1) < 1.5)  # corner rays: 1.3 m
        # and it tells the team where it is: the frame's pose
        _key, payload = statuses.get(timeout=5.0)
        status = Status.decode(payload)
        assert status.robot == robot and status.pose == pose and status.t == 0.5
    finally:
        status_sub.undeclare()
