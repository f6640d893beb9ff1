"""The agent's commands to a robot running ROS 2: velocities on ``cmd_vel``, or goals for Nav2.

``twist_stamped`` and ``twist``: each decision goes out at once as a ``geometry_msgs/TwistStamped``
(``Twist``) on the robot's ``cmd_vel``, and again at ``rate_hz`` while no newer one comes, as a
teleop or Nav2's controller publishes; once no decision came for ``watchdog_s`` (the agent stopped
deciding: no frames, a stall, its end), zero velocity goes out instead, at the same rate. A stamped
command carries the stamp of the image it answers, repeats and the watchdog's zeros too: a
controller that measures a command's age from its stamp (diff_drive_controller's
``cmd_vel_timeout``) stops the robot on its own when the agent falls silent, and a simulated robot
in lockstep knows which frame a command answers. A rig with a tilt head gets its tilt first, as a
``trajectory_msgs/JointTrajectory`` of one joint stamped the same.

``nav2``: the target, when it changes, as a ``geometry_msgs/PoseStamped`` on ``goal_pose`` in the
fixed frame, facing the gaze direction (what RViz's "Nav2 Goal" sends to bt_navigator); the
robot's own stack drives there. No velocities are sent.

Closing the sink sends zero velocity once more (twist modes).
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable

from robot_agent.decision import Decision
from swarm.config.ros2 import Ros2Config
from swarm.protocol.wire import Cmd
from swarm.ros2 import messages as rm
from swarm.ros2.messages import Stamp
from swarm.ros2.node import Ros2Node


class Ros2CommandSink:
    """Commands of one robot through ``node``, per ``config.cmd``; ``stamp_of(seq)`` gives the image
    stamp of frame ``seq`` (the frame source's), else the frame's own ``t`` is used.

    ``counters``: ``sent`` (decisions), ``repeated``, ``watchdog`` (zeros sent), ``goals``.
    """

    def __init__(self, node: Ros2Node, config: Ros2Config, stamp_of: Callable[[int], Stamp | None],
                 tilt_head: bool = False) -> None:  # fmt: skip
        self.config = config.cmd
        self.mode = self.config.mode
        self.types = node.context.types
        self._stamp_of = stamp_of
        self.counters: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._last: tuple[Stamp, float, float] | None = None  # (stamp, v, omega) of the last decision
        self._decided_at = 0.0
        self._goal: tuple[float, float, float] | None = None
        self._fixed_frame = config.fixed_frame
        self._stop = threading.Event()
        self._repeater: threading.Thread | None = None
        if self.mode == "nav2":
            self._pub = node.publisher(config.topic("goal"), rm.POSE_STAMPED)
            self._tilt = None
            return
        kind = rm.TWIST_STAMPED if self.mode == "twist_stamped" else rm.TWIST
        self._pub = node.publisher(config.topic("cmd"), kind)
        self._tilt = node.publisher(config.topic("tilt"), rm.JOINT_TRAJECTORY) if tilt_head else None
        self._joint = config.tilt.joint
        if self.config.rate_hz > 0:
            self._repeater = threading.Thread(target=self._repeat, name="cmd_vel", daemon=True)
            self._repeater.start()

    def describe(self) -> str:
        if self.mode == "nav2":
            return f"goals on {self._pub.topic} (Nav2)"
        tilt = f", tilt on {self._tilt.topic}" if self._tilt is not None else ""
        kind = "TwistStamped" if self.mode == "twist_stamped" else "Twist"
        rate = f"{self.config.rate_hz:g} Hz, watchdog {self.config.watchdog_s:g} s"
        return f"{kind} on {self._pub.topic} at {rate}{tilt}"

    def send(self, cmd: Cmd, decision: Decision, gaze_yaw: float | None = None) -> None:
        """Send the command of one decision (answering frame ``cmd.seq`` at ``cmd.t``)."""
        stamp = self._stamp_of(cmd.seq) or Stamp.from_seconds(max(cmd.t, 0.0))
        if self.mode == "nav2":
            self._send_goal(stamp, decision, gaze_yaw)
            return
        with self._lock:
            if self._tilt is not None and cmd.tilt is not None:
                self._tilt.publish(rm.joint_trajectory(self.types, stamp, self._joint, cmd.tilt))
            self._put(stamp, cmd.v, cmd.omega)
            self._last = (stamp, cmd.v, cmd.omega)
            self._decided_at = time.monotonic()
            self.counters["sent"] += 1

    def _put(self, stamp: Stamp, v: float, omega: float) -> None:
        if self.mode == "twist_stamped":
            self._pub.publish(rm.twist_stamped(self.types, stamp, self.config.frame_id, v, omega))
        else:
            self._pub.publish(rm.twist(self.types, v, omega))

    def _send_goal(self, stamp: Stamp, decision: Decision, gaze_yaw: float | None) -> None:
        if decision.target is None or decision.state == "done":
            return
        x, y = decision.target
        goal = (float(x), float(y), float(gaze_yaw or 0.0))
        if goal == self._goal:
            return
        self._goal = goal
        self._pub.publish(rm.pose_stamped(self.types, stamp, self._fixed_frame, *goal))
        self.counters["goals"] += 1

    def _repeat(self) -> None:
        period = 1.0 / self.config.rate_hz
        while not self._stop.wait(period):
            with self._lock:
                if self._last is None:
                    continue
                stamp, v, omega = self._last
                if time.monotonic() - self._decided_at > self.config.watchdog_s:
                    self._put(stamp, 0.0, 0.0)
                    self.counters["watchdog"] += 1
                else:
                    self._put(stamp, v, omega)
                    self.counters["repeated"] += 1

    def close(self) -> None:
        """Stop repeating; zero velocity once more (twist modes)."""
        self._stop.set()
        if self._repeater is not None:
            self._repeater.join(timeout=2.0)
        with self._lock:
            if self.mode != "nav2" and self._last is not None:
                self._put(self._last[0], 0.0, 0.0)
