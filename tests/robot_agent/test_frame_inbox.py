"""The agent's frame inbox keeps the newest frame: a driver faster than the agent loses the
older waiting frames (counted), not the agent's pace (robot_agent/frame_inbox.py)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from robot_agent.agent import Agent
from robot_agent.frame_inbox import FrameInbox
from swarm.protocol import bus
from swarm.protocol.wire import Camera, Cmd, Frame, Pose
from tests.support.map_server_mission import small_mission


def test_the_newest_frame_replaces_the_waiting_ones_and_they_are_counted():
    inbox = FrameInbox()
    assert inbox.take(timeout=0.01) is None
    for payload in (b"1", b"2", b"3"):
        inbox.put(payload)
    assert inbox.take(timeout=0.01) == b"3" and inbox.superseded == 2
    assert inbox.take(timeout=0.01) is None
    inbox.put(b"4")  # taken before the next came: nothing superseded
    assert inbox.take(timeout=0.01) == b"4" and inbox.superseded == 2


def test_a_waiting_agent_wakes_for_a_frame_put_from_another_thread():
    inbox = FrameInbox()
    threading.Timer(0.05, inbox.put, args=(b"frame",)).start()
    start = time.monotonic()
    assert inbox.take(timeout=5.0) == b"frame"
    assert time.monotonic() - start < 2.0


@pytest.mark.slow
def test_an_agent_behind_its_driver_answers_the_newest_frame_not_a_backlog():
    """Ten frames published before the agent takes one (a 20 Hz driver, a slower agent): it
    fuses and answers the tenth only and counts nine dropped; a first-in first-out queue
    answered all ten, each later than the last."""
    mission = small_mission()
    port = bus.free_port()
    agent_session = bus.open_session(listen=[bus.tcp_endpoint(port)])
    driver = bus.open_session(connect=[bus.tcp_endpoint(port)])
    try:
        agent = Agent(mission, "r1", agent_session, coordination=False)
        cmd_sub, answers = bus.subscribe_queue(driver, bus.key(mission.mission, "robot", "r1", "cmd"))
        frames = bus.reliable_publisher(driver, bus.key(mission.mission, "robot", "r1", "frame"))
        time.sleep(0.5)  # both subscriptions known to the other session
        rig = mission.rig_for("r1")
        camera = Camera(rig.width, rig.height, 80.0, 80.0, rig.width / 2, rig.height / 2, 0.1)
        depth = np.full((rig.height, rig.width), 1.5, np.float32)
        pose = Pose((0.5, 0.5, 0.3), (0.3, 0.0, 0.0))
        for seq in range(1, 11):
            frames.put(Frame("r1", seq, 0.05 * seq, pose, camera, depth=depth).encode())
        deadline = time.monotonic() + 10.0
        while agent.superseded_frames < 9 and time.monotonic() < deadline:
            time.sleep(0.02)
        agent.run(max_frames=1)
        _key, payload = answers.get(timeout=10.0)
        assert Cmd.decode(payload).seq == 10
        assert agent.superseded_frames == 9 and agent.frames_fused == 1
        assert agent.handle(b"not a frame") is None  # refused, logged and counted
        note = agent._dropped_frames_note()
        assert "9 older frames dropped" in note and "1 frames refused" in note
        time.sleep(0.3)
        assert answers.empty()
        cmd_sub.undeclare()
    finally:
        driver.close()
        agent_session.close()
