"""The ROS 2 messages a stereo robot and its driver exchange, built from numbers: camera images and
CameraInfo, transforms, the clock, velocity commands, Nav2 goals and a head's joint command.

Message objects are ``rosbags``' (``Ros2Types.new``), serialised by ``Ros2Types``. Stamps are kept
as ``Stamp`` (sec, nanosec): a float of seconds since 1970 holds only about 0.2 us, and a command
answering an image carries that image's stamp to the nanosecond.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from swarm.ros2.types import Ros2Types, time_fields

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF = "tf2_msgs/msg/TFMessage"
CLOCK = "rosgraph_msgs/msg/Clock"
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
JOINT_TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"


class Stamp(NamedTuple):
    """A ``builtin_interfaces/Time``: whole seconds and nanoseconds (0..999,999,999)."""

    sec: int
    nanosec: int

    @classmethod
    def of(cls, header_or_time: Any) -> Stamp:
        """The stamp of a ``std_msgs/Header`` (its ``stamp``) or of a ``Time``."""
        t = getattr(header_or_time, "stamp", header_or_time)
        return cls(int(t.sec), int(t.nanosec))

    @classmethod
    def from_seconds(cls, t: float) -> Stamp:
        return cls(**time_fields(t))

    @property
    def seconds(self) -> float:
        return self.sec + self.nanosec * 1e-9

    def time(self, types: Ros2Types) -> Any:
        return types.new("builtin_interfaces/msg/Time", sec=int(self.sec), nanosec=int(self.nanosec))

    def header(self, types: Ros2Types, frame_id: str) -> Any:
        return types.new("std_msgs/msg/Header", stamp=self.time(types), frame_id=str(frame_id))


def quaternion_of(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method: the largest of
    w, x, y, z found first, for precision)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    w, x, y, z = q
    return (w, x, y, z) if w >= 0 else (-w, -x, -y, -z)


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a turn by ``yaw`` rad about z."""
    return math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)


def image(types: Ros2Types, stamp: Stamp, frame_id: str, pixels: np.ndarray, encoding: str = "mono8") -> Any:
    """A ``sensor_msgs/Image`` of ``pixels``: uint8 gray (``mono8``; ``bgr8``/``rgb8`` repeat the gray
    in three channels), uint8 H x W x 3 colour in the encoding's order, or uint16 gray (``mono16``)."""
    pixels = np.asarray(pixels)
    if encoding in ("bgr8", "rgb8") and pixels.ndim == 2:
        pixels = np.repeat(pixels[:, :, None], 3, axis=2)
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    height, width = pixels.shape[:2]
    data = np.ascontiguousarray(pixels).view(np.uint8).reshape(-1)
    return types.new(
        IMAGE,
        header=stamp.header(types, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels * pixels.dtype.itemsize,
        data=data,
    )


def camera_info(
    types: Ros2Types,
    stamp: Stamp,
    frame_id: str,
    size: tuple[int, int],
    k: np.ndarray,
    d: np.ndarray,
    r: np.ndarray,
    p: np.ndarray,
    distortion_model: str = "plumb_bob",
) -> Any:
    """A ``sensor_msgs/CameraInfo`` (REP-104) of a camera whose images are ``size`` (width, height)."""
    roi = types.new(
        "sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    return types.new(
        CAMERA_INFO,
        header=stamp.header(types, frame_id),
        height=int(size[1]),
        width=int(size[0]),
        distortion_model=distortion_model,
        d=np.asarray(d, dtype=np.float64).reshape(-1),
        k=np.asarray(k, dtype=np.float64).reshape(9),
        r=np.asarray(r, dtype=np.float64).reshape(9),
        p=np.asarray(p, dtype=np.float64).reshape(12),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def rectified_pair_infos(
    fx: float, fy: float, cx: float, cy: float, baseline: float
) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
    """(K, D, R, P) of the left and right cameras of a rectified pair (no distortion, R = I, the right
    camera ``baseline`` m along the left's x axis: its P[0][3] = -fx * baseline)."""
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    left_p = np.hstack([k, np.zeros((3, 1))])
    right_p = left_p.copy()
    right_p[0, 3] = -fx * baseline
    d, r = np.zeros(5), np.eye(3)
    return (k, d, r, left_p), (k, d, r, right_p)


def transform(
    types: Ros2Types, stamp: Stamp, parent: str, child: str, xyz, wxyz: tuple[float, float, float, float]
) -> Any:
    """A ``geometry_msgs/TransformStamped``: X_parent = R(wxyz) X_child + xyz."""
    vector = types.new("geometry_msgs/msg/Vector3", x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))
    w, x, y, z = (float(v) for v in wxyz)
    rotation = types.new("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w)
    body = types.new("geometry_msgs/msg/Transform", translation=vector, rotation=rotation)
    return types.new(
        "geometry_msgs/msg/TransformStamped",
        header=stamp.header(types, parent),
        child_frame_id=str(child),
        transform=body,
    )


def tf_message(types: Ros2Types, transforms: list[Any]) -> Any:
    return types.new(TF, transforms=list(transforms))


def clock(types: Ros2Types, stamp: Stamp) -> Any:
    return types.new(CLOCK, clock=stamp.time(types))


def twist(types: Ros2Types, v: float, omega: float) -> Any:
    """A ``geometry_msgs/Twist``: ``v`` m/s along the base's x, ``omega`` rad/s about its z."""
    vec = "geometry_msgs/msg/Vector3"
    return types.new(TWIST, linear=types.new(vec, x=float(v), y=0.0, z=0.0),
                     angular=types.new(vec, x=0.0, y=0.0, z=float(omega)))  # fmt: skip


def twist_stamped(types: Ros2Types, stamp: Stamp, frame_id: str, v: float, omega: float) -> Any:
    return types.new(TWIST_STAMPED, header=stamp.header(types, frame_id), twist=twist(types, v, omega))


def pose_stamped(types: Ros2Types, stamp: Stamp, frame_id: str, x: float, y: float, yaw: float) -> Any:
    """A ``geometry_msgs/PoseStamped`` on the floor: (x, y) m facing ``yaw`` rad (a Nav2 goal)."""
    w, qx, qy, qz = yaw_quaternion(yaw)
    position = types.new("geometry_msgs/msg/Point", x=float(x), y=float(y), z=0.0)
    orientation = types.new("geometry_msgs/msg/Quaternion", x=qx, y=qy, z=qz, w=w)
    pose = types.new("geometry_msgs/msg/Pose", position=position, orientation=orientation)
    return types.new(POSE_STAMPED, header=stamp.header(types, frame_id), pose=pose)


def joint_trajectory(types: Ros2Types, stamp: Stamp, joint: str, position: float) -> Any:
    """A ``trajectory_msgs/JointTrajectory`` moving one joint to ``position`` (rad) at once, as a
    ros2_control joint_trajectory_controller takes it."""
    point = types.new(
        "trajectory_msgs/msg/JointTrajectoryPoint",
        positions=np.array([float(position)]),
        velocities=np.zeros(0),
        accelerations=np.zeros(0),
        effort=np.zeros(0),
        time_from_start=types.new("builtin_interfaces/msg/Duration", sec=0, nanosec=0),
    )
    header = stamp.header(types, "")
    return types.new(JOINT_TRAJECTORY, header=header, joint_names=[str(joint)], points=[point])
