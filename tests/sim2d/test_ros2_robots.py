"""The simulated ROS 2 robots (``sim2d.ros2_robots``) on loopback sessions: the agent's ROS 2 frame
source rebuilds each frame's camera pose from their tf tree, pixels and pinhole unchanged; a
command answers a frame only when stamped with its stamp (and, on a tilt head, with its tilt)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from robot_agent.frame_inbox import FrameInbox
from robot_agent.ros2_link import Ros2Link
from sim2d.render import camera_pose
from sim2d.ros2_robots import Ros2Robots
from swarm.config import load_mission
from swarm.protocol import bus
from swarm.protocol.wire import Cmd, Frame
from swarm.ros2 import messages as rm
from swarm.ros2.messages import Stamp
from tests.support.paths import CONFIGS

OFFICE = CONFIGS / "office.yaml"


@pytest.fixture
def world_and_agent():
    endpoint = bus.tcp_endpoint(bus.free_port())
    world = bus.open_session(listen=[endpoint], timestamping=True)
    agent = bus.open_session(connect=[endpoint], timestamping=True)
    mission = load_mission(OFFICE)
    one = mission.model_copy(update={"robots": mission.robots[:1]})
    robots = Ros2Robots(world, one, encoding="bgr8")
    link = Ros2Link.open(mission, "r1", agent)
    inbox = FrameInbox()
    link.frames.start(inbox)
    deadline = time.monotonic() + 10
    while robots.missing() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not robots.missing()
    yield mission, robots, link, inbox
    link.close()
    robots.close()
    agent.close()
    world.close()


def test_frames_come_back_with_their_pose_pixels_and_pinhole(world_and_agent):
    mission, robots, link, inbox = world_and_agent
    rig = mission.rig_for("r1")
    camera = rig.camera()
    rng = np.random.default_rng(0)
    for seq, (x, y, yaw, tilt) in enumerate(
        [(1.0, 5.0, 0.0, 0.0), (1.3, 5.2, 2.5, -0.4), (2.0, 4.0, -3.0, 0.3)], 1
    ):
        pose = camera_pose(x, y, yaw, rig.camera_height, math.radians(rig.pitch_deg) + tilt)
        left, right = (rng.integers(0, 255, (camera.height, camera.width), dtype=np.uint8) for _ in range(2))
        robots.publish(
            {"r1": Frame("r1", seq, 0.5 * seq, pose, camera, "raw8", left=left, right=right)}, 0.5 * seq
        )
        frame = inbox.take(10).frame()
        assert frame is not None, link.frames.all_counters()
        assert np.array_equal(frame.left, left) and np.array_equal(frame.right, right)  # bgr8 back to gray
        assert frame.camera.width == camera.width and frame.camera.fx == pytest.approx(camera.fx)
        assert frame.camera.baseline == pytest.approx(camera.baseline, rel=1e-12)
        assert np.allclose(frame.pose.xyz, pose.xyz, atol=1e-12), (frame.pose, pose)
        assert np.allclose(frame.pose.ypr, pose.ypr, atol=1e-12), (frame.pose, pose)
        assert frame.t == pytest.approx(0.5 * seq)


@pytest.mark.slow
def test_a_command_answers_the_frame_of_its_stamp_with_the_tilt(world_and_agent):
    mission, robots, link, inbox = world_and_agent
    rig = mission.rig_for("r1")
    camera = rig.camera()
    image = np.zeros((camera.height, camera.width), np.uint8)
    pose = camera_pose(1.0, 5.0, 0.0, rig.camera_height)
    robots.publish({"r1": Frame("r1", 7, 3.5, pose, camera, "raw8", left=image, right=image)}, 3.5)
    pending = inbox.take(10)
    assert pending.stamp == Stamp(3, 500_000_000)
    sink, types = link.commands, robots.robots["r1"].types
    assert robots.robots["r1"].head  # the office's rig has a tilt head: its answer needs the tilt too
    sink._pub.publish(rm.twist_stamped(types, Stamp(3, 0), "base_link", 0.5, 0.5))  # another frame's stamp
    sink.send(Cmd("r1", pending.seq, 3.5, 0.2, -0.1, tilt=-0.3), None)  # tilt first, then the twist
    cmd = robots.take(5.0)
    assert cmd == Cmd("r1", 7, 3.5, 0.2, -0.1, -0.3)
    sink.send(Cmd("r1", pending.seq, 3.5, 0.2, -0.1, tilt=-0.3), None)  # a repeat: no second answer
    assert robots.take(0.5) is None
