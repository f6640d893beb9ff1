"""A recording played as a ROS 2 robot's topics (``swarm replay asl|bag --ros2``), as ``ros2 bag
play`` would put a stereo camera's recording on rmw_zenoh: raw left and right ``sensor_msgs/Image``
(``mono8``), both ``sensor_msgs/CameraInfo`` (the calibration's K, D, R, P per camera, REP-104),
and the left camera's pose on ``tf`` (``fixed_frame -> camera``, the recording's ground truth),
in the robot's namespace of the mission's ``ros2`` settings.

Lockstep (default): each pair waits for the agent's ``cmd_vel`` (``TwistStamped``) stamped with the
pair's stamp, so none is lost whatever the agent's speed; ``realtime``: pairs leave at the
recorded rate. The agent rectifies the raw pairs from the CameraInfo and looks its pose up in tf:
the same frames as ``robot/<id>/frame`` replays carry (``replay.publisher``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable

import numpy as np
import zenoh

from replay.publisher import PublishLog
from swarm.config import Mission
from swarm.formats.stereo_calibration import StereoCalibration
from swarm.protocol.wire import Frame
from swarm.ros2 import messages as rm
from swarm.ros2.graph import History, Qos
from swarm.ros2.messages import Stamp
from swarm.ros2.node import Ros2Context
from swarm.streams.frames import RecordedPair

LOCKSTEP_QOS = Qos(history=History.KEEP_ALL, depth=0)  # reliable, BLOCK: no pair lost on a full queue
LEFT_FRAME, RIGHT_FRAME = "cam0", "cam1"


def camera_infos(calib: StereoCalibration) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """(K, D, R, P) of the left and right cameras of a calibration, as their CameraInfo holds them."""
    if calib.cameras is not None:
        return calib.cameras
    cx_right = calib.cx if calib.cx_right is None else calib.cx_right
    left, right = rm.rectified_pair_infos(calib.fx, calib.fy, calib.cx, calib.cy, calib.baseline)
    right[3][0, 2] = cx_right
    return left, right


class Ros2Player:
    """Publishes pairs of one robot as ROS 2 topics and waits for the agent's stamped answers."""

    def __init__(
        self, session: zenoh.Session, mission: Mission, robot: str, calib: StereoCalibration
    ) -> None:
        config = mission.ros2_for(robot)
        self.context = Ros2Context(session, config.domain_id, config.distro)
        self.types = self.context.types
        self.node = self.context.node("swarm_replay", config.namespace)
        self.fixed_frame = config.fixed_frame
        self.camera_frame = config.camera_frame or LEFT_FRAME
        self.infos = camera_infos(calib)
        self.model = "equidistant" if calib.fisheye else "plumb_bob"
        self.size = calib.image_size
        pub = self.node.publisher
        self._images = [pub(config.topic(side), rm.IMAGE, LOCKSTEP_QOS) for side in ("left", "right")]
        self._infos = [
            pub(config.topic(f"{s}_info"), rm.CAMERA_INFO, LOCKSTEP_QOS) for s in ("left", "right")
        ]
        self._tf = pub(config.topic("tf"), rm.TF, LOCKSTEP_QOS)
        self._answers: dict[Stamp, float] = {}  # stamp -> perf_counter time of the first answer
        self._cond = threading.Condition()
        self.node.subscription(config.topic("cmd"), rm.TWIST_STAMPED, self._on_cmd)

    def _on_cmd(self, msg, _info) -> None:
        with self._cond:
            self._answers.setdefault(Stamp.of(msg.header), time.perf_counter())
            self._cond.notify_all()

    def wait_for_agent(self, timeout: float) -> bool:
        """True once the agent subscribes to the images, CameraInfo and tf."""
        deadline = time.monotonic() + timeout
        pubs = [*self._images, *self._infos, self._tf]
        while not all(p.has_subscribers() for p in pubs):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.02)
        return True

    def send(self, pair: RecordedPair) -> Stamp:
        """The pair's pose on tf, its CameraInfo and images, all stamped with its time."""
        stamp = Stamp.from_seconds(pair.t)
        types = self.types
        pose = rm.transform(types, stamp, self.fixed_frame, self.camera_frame, pair.position,
                            rm.quaternion_of(pair.world_R_optical))  # fmt: skip
        self._tf.publish(rm.tf_message(types, [pose]))
        for k, (image, frame_id) in enumerate(((pair.left, self.camera_frame), (pair.right, RIGHT_FRAME))):
            height, width = image.shape[:2]
            encoding = "mono16" if image.dtype == np.uint16 else "mono8"
            info = rm.camera_info(types, stamp, frame_id, (width, height), *self.infos[k], self.model)
            self._infos[k].publish(info)
            self._images[k].publish(rm.image(types, stamp, frame_id, image, encoding))
        return stamp

    def _answered(self, stamp: Stamp, timeout: float) -> float | None:
        with self._cond:
            self._cond.wait_for(lambda: stamp in self._answers, timeout)
            return self._answers.get(stamp)

    def run(
        self,
        pairs: Iterable[tuple[RecordedPair, Frame]],
        realtime: bool = False,
        timeout: float = 60.0,
        after_each: Callable[[Frame, float | None], None] | None = None,
    ) -> PublishLog:
        """Send every pair (lockstep, or at the recorded times with ``realtime``); each pair's frame
        (as ``robot/<id>/frame`` would carry it) goes to ``after_each`` with the round trip."""
        log = PublishLog()
        t0_rec = t0_wall = None
        sent_at, stamps = [], []
        for pair, frame in pairs:
            now = time.perf_counter()
            if realtime:
                if t0_rec is None:
                    t0_rec, t0_wall = pair.t, now
                time.sleep(max(0.0, (pair.t - t0_rec) - (now - t0_wall)))
                now = time.perf_counter()
            sent_at.append(now)
            stamps.append(self.send(pair))
            rtt = None
            if not realtime:
                answered = self._answered(stamps[-1], timeout)
                rtt = None if answered is None else answered - now
                log.unanswered += rtt is None
            log.rows.append((frame.seq, frame.t, rtt))
            if after_each is not None:
                after_each(frame, rtt)
        log.sent_s = [t - sent_at[0] for t in sent_at] if sent_at else []
        if realtime and stamps:
            self._answered(stamps[-1], timeout)
            with self._cond:
                answers = dict(self._answers)
            log.rows = [(seq, t, answers[s] - sent if s in answers else None)
                        for (seq, t, _), s, sent in zip(log.rows, stamps, sent_at, strict=True)]  # fmt: skip
            log.unanswered = sum(rtt is None for _, _, rtt in log.rows)
        return log

    def close(self) -> None:
        self.node.close()
