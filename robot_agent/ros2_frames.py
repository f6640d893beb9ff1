"""A robot's frames from its ROS 2 topics (rmw_zenoh): the agent's frame source when the robot
runs ROS 2 instead of sending ``robot/<id>/frame``.

Subscribes to the left and right ``sensor_msgs/Image`` (or ``CompressedImage``), both
``sensor_msgs/CameraInfo``, ``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``) and, with
``use_sim_time``, ``/clock``. Left and right images are paired by header stamp within
``stamp_tolerance_s`` (``swarm.streams.stereo_sync``); a pair waits up to ``tf_wait_s`` for the
transforms around its stamp and for both cameras' CameraInfo; the left camera's pose is then looked
up in ``fixed_frame`` at the stamp (``swarm.streams.tf_buffer``). The pair goes to the agent's
inbox as a ``PendingFrame`` and becomes a frame only when the agent takes it (a newer pair
replacing it costs nothing): decoded (``swarm.streams.image_messages``), rectified from the
CameraInfo pair, posed in our axis convention (``swarm.streams.frames.make_frame``), as
``swarm replay bag`` does for the same messages.

Nothing a robot sends makes it raise: each refused message or pair is counted by a named reason
in ``counters`` (e.g. ``"unsupported image encoding"``, ``"camera_info not rectifiable"``,
``"tf loop"``, ``"image stamp in the future"``) and said in the agent's progress lines; the first
of each reason and one per 10 s are logged with the details.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np

from robot_agent.frame_inbox import FrameInbox
from swarm.config.ros2 import Ros2Config
from swarm.formats.calibration_formats import CameraInfo, stereo_from_camera_infos
from swarm.formats.errors import InputError
from swarm.formats.pixel_bits import SignificantBits, to_8_bits
from swarm.formats.stereo_calibration import StereoCalibration
from swarm.log_limit import LogLimiter
from swarm.protocol.wire import Frame
from swarm.ros2.graph import LATCHED_QOS, SENSOR_QOS, Qos
from swarm.ros2.messages import CAMERA_INFO, CLOCK, COMPRESSED_IMAGE, IMAGE, TF, Stamp
from swarm.ros2.node import Ros2Node
from swarm.streams.frames import RecordedPair, make_frame, rectified_camera
from swarm.streams.image_messages import camera_info, decode_image
from swarm.streams.stereo_sync import StereoSync
from swarm.streams.tf_buffer import GAP, LOOP, NO_PATH, NOT_YET, TfBuffer, TfLookupError

log = logging.getLogger("swarm.agent")

#: lookups a pair waits out (tf_wait_s), as tf2's MessageFilter: the transform that answers it
#: (or repairs the tree) may be on its way
WAIT_FOR = (NOT_YET, NO_PATH, GAP, LOOP)
WAITING_PAIRS = 8  # pairs waiting for their transforms at most (the newest kept)
STAMPS_KEPT = 64  # frame seq -> image stamp, for the commands answering them
TF_REASONS = {
    "not_yet": "no tf at the image stamp",
    "too_old": "tf older than the image",
    "gap": "no tf near the image stamp",
    "no_path": "no tf path to the camera",
    "loop": "tf loop",
}
REFUSED_TRANSFORMS = {
    "unusable": "unusable transform (NaN or a zero quaternion)",
    "self": "transform of a frame to itself",
    "frames": "tf frames beyond the limit",
}


def image_problem(exc: Exception) -> str:
    """The counter name of an image that does not decode (``decode_image``'s RecordingError)."""
    text = str(exc)
    if "is not supported" in text:
        return "unsupported image encoding"
    if "needs step" in text:
        return "image size does not match its data"
    if "compressed" in text:
        return "compressed image does not decode"
    return "image does not decode"


def _info_key(msg: Any) -> tuple:
    """What of a CameraInfo message the calibration depends on."""
    numbers = tuple(np.asarray(getattr(msg, name), dtype=np.float64).tobytes() for name in "kdrp")
    roi = msg.roi
    sizes = (
        int(msg.width),
        int(msg.height),
        int(msg.binning_x),
        int(msg.binning_y),
        int(roi.width),
        int(roi.height),
    )
    return (str(msg.distortion_model), *numbers, *sizes, int(roi.x_offset), int(roi.y_offset))


class PendingFrame:
    """A paired stereo image with its pose, waiting in the agent's inbox; ``frame()`` makes it."""

    def __init__(self, source: Ros2FrameSource, seq: int, stamp: Stamp, left: Any, right: Any,
                 infos: tuple[Any, Any], position: np.ndarray, rotation: np.ndarray) -> None:  # fmt: skip
        self.source, self.seq, self.stamp = source, seq, stamp
        self.left, self.right, self.infos = left, right, infos
        self.position, self.rotation = position, rotation

    def frame(self) -> Frame | None:
        """The robot frame of this pair; None when it cannot be made (counted, logged)."""
        return self.source.make(self)


class Ros2FrameSource:
    """The frames of one robot from ``node``'s subscriptions, per ``config`` (a robot's resolved
    ``Ros2Config``). ``start(inbox)`` begins handing ``PendingFrame``s to the agent's inbox."""

    def __init__(self, node: Ros2Node, config: Ros2Config, robot_id: str,
                 wall_clock: Callable[[], float] = time.time) -> None:  # fmt: skip
        self.config, self.robot_id = config, robot_id
        self.counters: Counter[str] = Counter()
        self.pairs_made = 0
        self._wall = wall_clock
        self._lock = threading.Lock()
        self._sync = StereoSync(config.stamp_tolerance_s, SENSOR_QOS.depth)
        self._tf = TfBuffer()
        self._infos: dict[str, Any] = {"left": None, "right": None}
        self._waiting: list[tuple[float, Stamp, Any, Any, float]] = []  # (t, stamp, left, right, since)
        self._inbox: FrameInbox | None = None
        self._sim_now: float | None = None  # /clock, with use_sim_time
        self._newest_t = -np.inf  # the stamp of the newest pair handed on
        self.stamps: OrderedDict[int, Stamp] = OrderedDict()
        self._calibration: tuple[tuple, StereoCalibration] | None = None
        self._bits = SignificantBits({}, 0)
        self._log = LogLimiter(log)
        self._timer: threading.Timer | None = None  # gives up on the waiting pairs after tf_wait_s
        self._node = node
        self.topics = {name: config.topic(name) for name in ("left", "right", "left_info", "right_info")}
        self._subs: list = []

    # -- the agent's side --------------------------------------------------------------------
    def start(self, inbox: FrameInbox) -> None:
        """Subscribe, and hand pairs to ``inbox`` from now on (the agent calls it when it listens)."""
        with self._lock:
            self._inbox = inbox
        node, config = self._node, self.config
        image_type = COMPRESSED_IMAGE if config.compressed else IMAGE
        for side in ("left", "right"):
            self._subscribe(side, image_type, self._on_image, SENSOR_QOS)
            self._subscribe(f"{side}_info", CAMERA_INFO, self._on_info, SENSOR_QOS)
        self._subs.append(node.subscription(config.topic("tf"), TF, self._on_tf, Qos(depth=100)))
        static = dataclasses.replace(LATCHED_QOS, depth=100)  # latched: a late agent gets them
        self._subs.append(node.subscription(config.topic("tf_static"), TF, self._on_tf_static, static))
        if config.use_sim_time:
            self._subs.append(node.subscription(config.topic("clock"), CLOCK, self._on_clock, Qos(depth=1)))

    def _subscribe(self, name: str, type_name: str, callback, qos: Qos) -> None:
        side = name.split("_")[0]
        subscription = self._node.subscription(
            self.topics[name], type_name, lambda m, _: callback(side, m), qos
        )
        self._subs.append(subscription)

    def describe(self) -> str:
        """Where the frames come from, for the agent's "waiting for frames on ..." line."""
        c, topics = self.config, self.topics
        return (
            f"ROS 2 topics {topics['left']} + {topics['right']} (CameraInfo {topics['left_info']}, "
            f"{topics['right_info']}; tf {c.topic('tf')}, {c.topic('tf_static')}; the camera in "
            f"{c.fixed_frame}; domain {c.domain_id}, {c.distro})"
        )

    def notes(self) -> str:
        """What was refused so far, by reason, for the progress lines (empty when nothing was)."""
        counts = ", ".join(f"{n:,} {reason}" for reason, n in sorted(self.all_counters().items()) if n)
        return f"ROS 2 input dropped: {counts}" if counts else ""

    def all_counters(self) -> dict[str, int]:
        """``counters``, the pairing's drops and the subscriptions' refusals, by name."""
        with self._lock:
            out = dict(self.counters + self._sync.dropped)
            for sub in self._subs:
                for reason, n in sub.refused.items():
                    out[f"{reason} message on {sub.topic}"] = n
        return out

    def stamp_of(self, seq: int) -> Stamp | None:
        """The image stamp of the frame numbered ``seq`` (for the command answering it)."""
        with self._lock:
            return self.stamps.get(seq)

    def close(self) -> None:
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
            self._waiting.clear()
        for sub in self._subs:
            sub.close()
        self._subs = []

    # -- counting --------------------------------------------------------------------------
    def _count(self, reason: str, detail: str = "") -> None:
        self.counters[reason] += 1
        self._log.warning(reason, "%s: ROS 2 input refused: %s%s", self.robot_id, reason,
                          f" ({detail})" if detail else "")  # fmt: skip

    def _future(self, t: float) -> bool:
        now = self._sim_now if self.config.use_sim_time else self._wall()
        return now is not None and t > now + self.config.max_future_s

    # -- callbacks (Zenoh's threads) ---------------------------------------------------------
    def _on_clock(self, msg: Any, _info: Any) -> None:
        with self._lock:
            self._sim_now = Stamp.of(msg.clock).seconds

    def _on_image(self, side: str, msg: Any) -> None:
        stamp = Stamp.of(msg.header)
        with self._lock:
            if self._future(stamp.seconds):
                self._count("image stamp in the future", f"{side} image at {stamp.seconds:.3f} s")
                return
            for t, left, right in self._sync.add(side, stamp.seconds, (stamp, msg)):
                if len(self._waiting) >= WAITING_PAIRS:
                    self._waiting.pop(0)
                    self.counters["pair superseded while waiting for tf"] += 1
                self._waiting.append((t, left[0], left[1], right[1], time.monotonic()))
            self._release()
            self._arm_timer()

    def _on_info(self, side: str, msg: Any) -> None:
        with self._lock:
            self._infos[side] = msg
            self._release()

    def _on_tf_static(self, msg: Any, _info: Any) -> None:
        self._on_tf(msg, _info, static=True)

    def _on_tf(self, msg: Any, _info: Any, static: bool = False) -> None:
        with self._lock:
            for tf in msg.transforms:
                stamp = Stamp.of(tf.header).seconds
                if not static and self._future(stamp):
                    self._count(
                        "tf stamp in the future",
                        f"{tf.header.frame_id} -> {tf.child_frame_id} at {stamp:.3f} s",
                    )
                    continue
                p, q = tf.transform.translation, tf.transform.rotation
                refused = self._tf.add(tf.header.frame_id, tf.child_frame_id, stamp, (p.x, p.y, p.z),
                                       (q.w, q.x, q.y, q.z), static)  # fmt: skip
                if refused:
                    self._count(REFUSED_TRANSFORMS[refused], f"{tf.header.frame_id} -> {tf.child_frame_id}")
            self._release()

    def _arm_timer(self) -> None:
        """Look at the waiting pairs again once their wait is over, though no message comes."""
        if self._waiting and self._timer is None:
            self._timer = threading.Timer(self.config.tf_wait_s + 0.005, self._on_timer)
            self._timer.daemon = True
            self._timer.start()

    def _on_timer(self) -> None:
        with self._lock:
            self._timer = None
            self._release()
            self._arm_timer()

    def _release(self) -> None:
        """Hand on the newest waiting pair whose transforms and CameraInfo are there; drop the older
        ones, and those that waited longer than ``tf_wait_s`` (counted by why). Under the lock."""
        now = time.monotonic()
        for k in range(len(self._waiting) - 1, -1, -1):
            t, stamp, left, right, since = self._waiting[k]
            expired = now - since > self.config.tf_wait_s
            if t <= self._newest_t:
                del self._waiting[k]
                self._count("image stamp not after the last frame's", f"pair at {t:.3f} s")
                continue
            infos = (self._infos["left"], self._infos["right"])
            if None in infos:
                if expired:
                    del self._waiting[k]
                    self._count("no camera_info yet", f"pair at {t:.3f} s")
                continue
            frame = self.config.camera_frame or left.header.frame_id
            tolerance = self.config.tf_tolerance_s
            try:
                position, rotation = self._tf.lookup(
                    self.config.fixed_frame, frame, t, tolerance, not expired
                )
            except TfLookupError as exc:
                if exc.reason in WAIT_FOR and not expired:  # the transforms may come yet
                    continue
                del self._waiting[k]
                self._count(
                    TF_REASONS[exc.reason], f"{self.config.fixed_frame} -> {frame} at {t:.3f} s: {exc}"
                )
                continue
            if k:
                self.counters["pair superseded while waiting for tf"] += k
            del self._waiting[: k + 1]
            self._hand_on(t, stamp, left, right, infos, position, rotation)
            return

    def _hand_on(self, t: float, stamp: Stamp, left, right, infos, position, rotation) -> None:
        self._newest_t = t
        self.pairs_made += 1
        seq = self.pairs_made
        self.stamps[seq] = stamp
        while len(self.stamps) > STAMPS_KEPT:
            self.stamps.popitem(last=False)
        if self._inbox is not None:
            self._inbox.put(PendingFrame(self, seq, stamp, left, right, infos, position, rotation))

    # -- making the frame (the agent's thread) -------------------------------------------------
    def make(self, pending: PendingFrame) -> Frame | None:
        """The frame of a pending pair, or None (counted by reason)."""
        where = f"pair at {pending.stamp.seconds:.3f} s"
        try:
            left = decode_image(pending.left, self.topics["left"])
            right = decode_image(pending.right, self.topics["right"])
        except InputError as exc:
            with self._lock:
                self._count(image_problem(exc), str(exc))
            return None
        if left.shape[:2] != right.shape[:2]:
            with self._lock:
                self._count(
                    "left and right images differ in size", f"{where}: {left.shape} and {right.shape}"
                )
            return None
        try:
            calib = self._calibration_of(pending.infos, (left.shape[1], left.shape[0]))
        except InputError as exc:
            with self._lock:
                self._count("camera_info not rectifiable", str(exc))
            return None
        left, right = self._eight_bits(left), self._eight_bits(right)
        pair = RecordedPair(pending.stamp.seconds, left, right, pending.position, pending.rotation)
        try:
            return make_frame(self.robot_id, pending.seq, pair, calib, rectified_camera(calib))
        except (ValueError, InputError) as exc:
            with self._lock:
                self._count("image does not fit its camera_info", str(exc))
            return None

    def _eight_bits(self, image: np.ndarray) -> np.ndarray:
        if image.dtype != np.uint16:
            return image
        bits = self.config.pixel_bits
        if bits is None:  # the bits of the brightest pixel seen so far (bits only grow)
            self._bits.add(image)
            bits = self._bits.bits
        return to_8_bits(image, bits)

    def _calibration_of(self, infos: tuple[Any, Any], size: tuple[int, int]) -> StereoCalibration:
        """The stereo calibration of the two CameraInfo messages (made once while they stay the
        same). The images' size is checked first: the rectification maps are the size the
        CameraInfo claims."""
        key = tuple(_info_key(m) for m in infos)
        if self._calibration is not None and self._calibration[0] == (key, size):
            return self._calibration[1]
        cameras = []
        for side, msg in zip(("left", "right"), infos, strict=True):
            info = camera_info(msg, self.topics[f"{side}_info"])
            if (info.width, info.height) != size:
                raise InputError(f"{self.topics[f'{side}_info']}: {info.width}x{info.height}, the images "
                                 f"are {size[0]}x{size[1]}")  # fmt: skip
            cameras.append(self._as_rectified(info) if self.config.rectified else info)
        calib = stereo_from_camera_infos(*cameras)
        rectified_camera(calib)  # refuses what a frame cannot carry (two principal points)
        self._calibration = ((key, size), calib)
        return calib

    @staticmethod
    def _as_rectified(info: CameraInfo) -> CameraInfo:
        """A camera whose images are rectified already: P alone describes them."""
        return dataclasses.replace(info, k=info.p[:, :3].copy(), d=np.zeros(0), r=np.eye(3))
