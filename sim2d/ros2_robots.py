"""The simulated robots as ROS 2 robots over rmw_zenoh (``swarm sim world --ros2``): what each
robot's drivers would publish, and its ``cmd_vel`` taken as its base controller takes it.

Per robot, in its namespace (the mission's ``ros2`` settings, as its agent reads them), each tick:

* ``/clock`` (``rosgraph_msgs/Clock``, the simulated time: agents run with ``use_sim_time``);
* ``tf``: ``map -> odom`` (the start pose), ``odom -> base_link`` (the pose since the start) and,
  on a tilt head, ``base_link -> camera_link`` (its tilt, as robot_state_publisher sends a joint);
* the left and right rectified images (``sensor_msgs/Image``, ``mono8`` or ``bgr8``) and their
  ``CameraInfo`` (no distortion, R = I, the right camera's P[0][3] = -fx * baseline), stamped with
  the simulated time, in ``camera_left_optical_frame`` / ``camera_right_optical_frame``;
* once, latched on ``tf_static``: ``base_link -> camera_link`` (a fixed rig: camera height and
  mounting pitch) and ``camera_link -> camera_{left,right}_optical_frame`` (REP-103's optical axes).

It takes ``geometry_msgs/TwistStamped`` on ``cmd_vel`` (the lockstep clock needs the stamp: a
command answers the images stamped the same) and, on a tilt head, the tilt as a
``trajectory_msgs/JointTrajectory`` stamped the same. Repeats of a command and commands of older
stamps are ignored; a robot's answer is complete when both have come. Publishers are reliable and
keep-all, so no frame of the lockstep world is dropped on a full queue (a camera would not care).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Any

import numpy as np
import zenoh

from swarm.config import Mission
from swarm.protocol.wire import BODY_FROM_OPTICAL, Cmd, Frame
from swarm.ros2 import messages as rm
from swarm.ros2.graph import LATCHED_QOS, History, Qos
from swarm.ros2.messages import Stamp
from swarm.ros2.node import Ros2Context

NODE_NAME = "sim_robot"
#: reliable, keep all: Zenoh's congestion control BLOCK, so the lockstep world loses no frame
LOCKSTEP_QOS = Qos(history=History.KEEP_ALL, depth=0)
OPTICAL = rm.quaternion_of(BODY_FROM_OPTICAL)  # camera_link (x forward, z up) -> optical frame


def pitch_quaternion(pitch: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a turn by ``pitch`` rad about y (positive looks down, as the wire's pitch)."""
    return math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0


class _Robot:
    """One robot's publishers and subscriptions, and the commands it has been given."""

    def __init__(self, ctx: Ros2Context, mission: Mission, rid: str, encoding: str, commands) -> None:
        config = mission.ros2_for(rid)
        self.rid, self.encoding, self.types = rid, encoding, ctx.types
        rig = mission.rig_for(rid)
        if rig.mode != "stereo":
            raise ValueError(
                f"robot {rid}: a simulated ROS 2 robot publishes stereo pairs; its rig is in {rig.mode} mode"
            )
        self.head = rig.tilt_range_deg > 0
        self.mount_pitch = math.radians(rig.pitch_deg)
        self.height = rig.camera_height
        start = mission.start_of(rid)  # where map -> odom is: the simulated robot's start
        self.start = (start.x, start.y, start.yaw)
        self.node = ctx.node(NODE_NAME, config.namespace)
        pub = self.node.publisher
        self.images = {side: pub(config.topic(side), rm.IMAGE, LOCKSTEP_QOS) for side in ("left", "right")}
        self.infos = {
            side: pub(config.topic(f"{side}_info"), rm.CAMERA_INFO, LOCKSTEP_QOS)
            for side in ("left", "right")
        }
        self.tf = pub(config.topic("tf"), rm.TF, LOCKSTEP_QOS)
        self.tf_static = pub(config.topic("tf_static"), rm.TF, LATCHED_QOS)
        self.fixed_frame = config.fixed_frame
        self.node.subscription(config.topic("cmd"), rm.TWIST_STAMPED, lambda m, _: commands(rid, "twist", m))
        if self.head:
            tilt = config.topic("tilt")
            self.node.subscription(tilt, rm.JOINT_TRAJECTORY, lambda m, _: commands(rid, "tilt", m))
        self.static_sent = False
        self.distortion: np.ndarray | None = None  # D the CameraInfo claims (None: none, as rendered)

    def publish_static(self, stamp: Stamp, baseline: float) -> None:
        transforms = []
        if not self.head:
            transforms.append(self._camera_link(stamp, 0.0))
        for side, y in (("left", 0.0), ("right", -baseline)):  # the right camera on the left's +x optical
            transforms.append(rm.transform(self.types, stamp, "camera_link", f"camera_{side}_optical_frame",
                                           (0.0, y, 0.0), OPTICAL))  # fmt: skip
        self.tf_static.publish(rm.tf_message(self.types, transforms))
        self.static_sent = True

    def _camera_link(self, stamp: Stamp, tilt: float) -> Any:
        pitch = pitch_quaternion(self.mount_pitch + tilt)
        return rm.transform(self.types, stamp, "base_link", "camera_link", (0.0, 0.0, self.height), pitch)

    def publish(self, frame: Frame, stamp: Stamp) -> None:
        """The tick's transforms, then CameraInfo and images (a frame's pose is its camera's)."""
        types, (x0, y0, yaw0) = self.types, self.start
        x, y, _ = frame.pose.xyz
        yaw, pitch, _ = frame.pose.ypr
        dx, dy = x - x0, y - y0
        c, s = math.cos(yaw0), math.sin(yaw0)
        odom_xy = (c * dx + s * dy, -s * dx + c * dy, 0.0)
        dynamic = [
            rm.transform(types, stamp, self.fixed_frame, "odom", (x0, y0, 0.0), rm.yaw_quaternion(yaw0)),
            rm.transform(types, stamp, "odom", "base_link", odom_xy, rm.yaw_quaternion(yaw - yaw0)),
        ]
        if self.head:
            dynamic.append(self._camera_link(stamp, pitch - self.mount_pitch))
        self.tf.publish(rm.tf_message(types, dynamic))
        cam = frame.camera
        infos = rm.rectified_pair_infos(cam.fx, cam.fy, cam.cx, cam.cy, cam.baseline)
        if self.distortion is not None:  # a benchmark's: the agent undistorts (wrongly) each pair
            infos = tuple((k, self.distortion, r, p) for k, _d, r, p in infos)
        for side, (k, d, r, p), pixels in zip(
            ("left", "right"), infos, (frame.left, frame.right), strict=True
        ):
            optical = f"camera_{side}_optical_frame"
            info = rm.camera_info(types, stamp, optical, (cam.width, cam.height), k, d, r, p)
            self.infos[side].publish(info)
            self.images[side].publish(rm.image(types, stamp, optical, pixels, self.encoding))


class Ros2Robots:
    """Every robot of ``mission`` as a ROS 2 robot on ``session`` (a ``sim2d.robot_link.RobotLink``)."""

    def __init__(self, session: zenoh.Session, mission: Mission, encoding: str = "mono8") -> None:
        if encoding not in ("mono8", "bgr8", "rgb8"):
            raise ValueError(f"image encoding {encoding!r}: mono8, bgr8 or rgb8")
        self.rejected = 0
        self._lock = threading.Lock()
        self._ready: list[Cmd] = []
        self._cond = threading.Condition(self._lock)
        self._seq_of: OrderedDict[Stamp, int] = OrderedDict()  # the stamps of the recent ticks
        self._answers: dict[tuple[str, Stamp], dict[str, Any]] = {}
        contexts: dict[tuple[int, str], Ros2Context] = {}
        self.robots: dict[str, _Robot] = {}
        self._clocks = []
        for rid in mission.robot_ids:
            config = mission.ros2_for(rid)
            key = (config.domain_id, config.distro)
            if key not in contexts:
                ctx = contexts[key] = Ros2Context(session, *key)
                clock_node = ctx.node("sim_clock")
                clock = clock_node.publisher(config.topic("clock"), rm.CLOCK, LOCKSTEP_QOS)
                self._clocks.append((clock_node, clock))
            self.robots[rid] = _Robot(contexts[key], mission, rid, encoding, self._on_command)
        first = mission.ros2_for(mission.robot_ids[0])
        self.where = f"{first.topic('left')} ... (ROS 2, domain {first.domain_id})"

    def missing(self) -> list[str]:
        """Robots whose image, CameraInfo or tf publishers no subscription (agent) matches yet."""
        out = []
        for rid, robot in self.robots.items():
            pubs = [*robot.images.values(), *robot.infos.values(), robot.tf]
            if not all(p.has_subscribers() for p in pubs):
                out.append(rid)
        return out

    def publish(self, frames: dict[str, Frame], t: float) -> None:
        stamp = Stamp.from_seconds(t)
        with self._lock:
            self._seq_of[stamp] = next(iter(frames.values())).seq
            while len(self._seq_of) > 4:
                self._seq_of.popitem(last=False)
        for _node, clock in self._clocks:
            clock.publish(rm.clock(clock.types, stamp))
        for rid, frame in frames.items():
            robot = self.robots[rid]
            if not robot.static_sent:
                robot.publish_static(stamp, frame.camera.baseline)
            robot.publish(frame, stamp)

    def _on_command(self, rid: str, kind: str, msg: Any) -> None:
        stamp = rm.Stamp.of(msg.header)
        with self._cond:
            seq = self._seq_of.get(stamp)
            if seq is None:
                return  # a repeat of an older command, or the watchdog's zero: not an answer
            answer = self._answers.setdefault((rid, stamp), {})
            if kind in answer:
                return  # a repeat
            if kind == "tilt":
                positions = msg.points[0].positions if msg.points else []
                answer["tilt"] = float(positions[0]) if len(positions) else None
            else:
                answer["twist"] = (float(msg.twist.linear.x), float(msg.twist.angular.z))
            if "twist" in answer and ("tilt" in answer or not self.robots[rid].head):
                v, omega = answer["twist"]
                tilt = answer.get("tilt")
                self._ready.append(Cmd(rid, seq, stamp.seconds, v, omega, tilt))
                self._cond.notify()
            for key in [k for k in self._answers if k[1] not in self._seq_of]:
                del self._answers[key]

    def take(self, timeout: float) -> Cmd | None:
        with self._cond:
            if not self._ready:
                self._cond.wait(timeout)
            return self._ready.pop(0) if self._ready else None

    def close(self) -> None:
        for robot in self.robots.values():
            robot.node.close()
        for node, _clock in self._clocks:
            node.close()
