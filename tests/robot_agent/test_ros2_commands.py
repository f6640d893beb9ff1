"""The agent's commands to a ROS 2 robot (``robot_agent.ros2_commands``), read by a subscriber on
another loopback session: TwistStamped stamped with the image it answers, repeated at the rate,
zero after the watchdog and at close; plain Twist; a tilt head's JointTrajectory; Nav2 goals."""

from __future__ import annotations

import math
import queue
import time

import pytest

from robot_agent.decision import Decision
from robot_agent.ros2_commands import Ros2CommandSink
from swarm.config.ros2 import Ros2Config
from swarm.protocol import bus
from swarm.protocol.wire import Cmd
from swarm.ros2 import messages as rm
from swarm.ros2.messages import Stamp
from swarm.ros2.node import Ros2Context


@pytest.fixture
def contexts():
    endpoint = bus.tcp_endpoint(bus.free_port())
    a = bus.open_session(listen=[endpoint], timestamping=True)
    b = bus.open_session(connect=[endpoint], timestamping=True)
    yield Ros2Context(a), Ros2Context(b)
    b.close()
    a.close()


def _listen(ctx, topic, type_name):
    got: queue.Queue = queue.Queue()
    ctx.node("robot", "/r1").subscription(topic, type_name, lambda m, _i: got.put((time.monotonic(), m)))
    return got


def _config(**cmd) -> Ros2Config:
    return Ros2Config(cmd=cmd).for_robot("r1")


@pytest.mark.slow
def test_twist_stamped_answers_carry_the_image_stamp_repeat_and_stop_on_the_watchdog(contexts):
    agent_ctx, robot_ctx = contexts
    twists = _listen(robot_ctx, "/r1/cmd_vel", rm.TWIST_STAMPED)
    tilts = _listen(robot_ctx, "/r1/camera_tilt_controller/joint_trajectory", rm.JOINT_TRAJECTORY)
    stamp = Stamp(1_764_000_000, 123_456_789)  # a float of seconds would lose the nanoseconds
    sink = Ros2CommandSink(agent_ctx.node("swarm_agent", "/r1"), _config(rate_hz=20, watchdog_s=0.3),
                           {7: stamp}.get, tilt_head=True)  # fmt: skip
    time.sleep(0.3)
    sent = time.monotonic()
    sink.send(Cmd("r1", 7, stamp.seconds, 0.3, -0.2, tilt=-0.5), Decision(0.3, -0.2, "drive", (1.0, 2.0)))
    _, tilt = tilts.get(timeout=5)
    assert Stamp.of(tilt.header) == stamp and tilt.joint_names == ["camera_tilt_joint"]
    assert list(tilt.points[0].positions) == [-0.5]
    received = [twists.get(timeout=5) for _ in range(12)]  # about 0.6 s at 20 Hz
    assert all(Stamp.of(m.header) == stamp for _, m in received)
    assert all(m.header.frame_id == "base_link" for _, m in received)
    values = [(m.twist.linear.x, m.twist.angular.z) for _, m in received]
    zero = values.index((0.0, 0.0))  # the decision, repeated, then the watchdog's zeros only
    assert zero >= 2 and set(values[:zero]) == {(0.3, -0.2)} and set(values[zero:]) == {(0.0, 0.0)}
    assert received[zero][0] - sent >= 0.25  # not before the watchdog's 0.3 s (less a little)
    assert sink.counters["sent"] == 1 and sink.counters["repeated"] >= 2 and sink.counters["watchdog"] >= 1
    sink.close()


def test_plain_twist_without_repeats_and_zero_at_close(contexts):
    agent_ctx, robot_ctx = contexts
    twists = _listen(robot_ctx, "/r1/cmd_vel", rm.TWIST)
    sink = Ros2CommandSink(
        agent_ctx.node("swarm_agent", "/r1"), _config(mode="twist", rate_hz=0), lambda s: None
    )
    time.sleep(0.3)
    sink.send(Cmd("r1", 1, 5.0, 0.4, 0.1), Decision(0.4, 0.1, "drive"))  # no stamp known: the frame's t
    _, first = twists.get(timeout=5)
    assert (first.linear.x, first.angular.z) == (0.4, 0.1)
    sink.close()
    _, last = twists.get(timeout=5)
    assert (last.linear.x, last.angular.z) == (0.0, 0.0)
    assert twists.empty()


@pytest.mark.slow
def test_nav2_mode_sends_each_new_target_as_a_goal_facing_the_gaze(contexts):
    agent_ctx, robot_ctx = contexts
    goals = _listen(robot_ctx, "/r1/goal_pose", rm.POSE_STAMPED)
    velocities = _listen(robot_ctx, "/r1/cmd_vel", rm.TWIST_STAMPED)
    sink = Ros2CommandSink(agent_ctx.node("swarm_agent", "/r1"), _config(mode="nav2"), lambda s: None)
    time.sleep(0.3)
    steps = [((2.0, 3.0), "drive"), ((2.0, 3.0), "drive"), ((4.0, 1.0), "drive"), ((4.0, 1.0), "done")]
    for seq, (target, state) in enumerate(steps, start=1):
        sink.send(
            Cmd("r1", seq, float(seq), 0.3, 0.0), Decision(0.3, 0.0, state, target), gaze_yaw=math.pi / 2
        )
    received = [goals.get(timeout=5)[1] for _ in range(2)]
    assert [(g.pose.position.x, g.pose.position.y) for g in received] == [(2.0, 3.0), (4.0, 1.0)]
    assert all(g.header.frame_id == "map" for g in received)
    q = received[0].pose.orientation
    assert 2 * math.atan2(q.z, q.w) == pytest.approx(math.pi / 2)
    time.sleep(0.3)
    assert goals.empty() and velocities.empty() and sink.counters["goals"] == 2
    sink.close()
