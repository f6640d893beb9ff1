"""A ROS 1 / ROS 2 bag writer for the replay tests, on ``rosbags``' own writers (no ROS install)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from rosbags.typesys import Stores, get_typestore


class BagWriter:
    """Writes Image / CompressedImage / CameraInfo / PoseStamped / TFMessage to a ROS 1 or 2 bag."""

    def __init__(self, path: Path, ros: int) -> None:
        self.ros = ros
        if ros == 1:
            from rosbags.rosbag1 import Writer

            self.store = get_typestore(Stores.ROS1_NOETIC)
            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import Writer

            self.store = get_typestore(Stores.ROS2_HUMBLE)
            self.writer = Writer(path, version=9)
        self.conns: dict[str, object] = {}
        self.t = self.store.types

    def __enter__(self) -> BagWriter:
        self.writer.open()
        return self

    def __exit__(self, *exc) -> None:
        self.writer.close()

    def header(self, t: float, frame: str = "cam0"):
        stamp = self.t["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int(round((t % 1) * 1e9)))
        kwargs = {"seq": 0} if self.ros == 1 else {}
        return self.t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **kwargs)

    def write(self, topic: str, msgtype: str, msg, t: float, latched: bool = False) -> None:
        """``latched``: a latched topic (ROS 1) / transient-local QoS (ROS 2), as /tf_static is."""
        if topic not in self.conns:
            kwargs = {}
            if latched and self.ros == 1:
                kwargs = {"latching": 1}
            elif latched:
                from rosbags import interfaces as q

                never = q.QosTime(2147483647, 4294967295)
                qos = q.Qos(
                    q.QosHistory.KEEP_LAST, 1, q.QosReliability.RELIABLE, q.QosDurability.TRANSIENT_LOCAL,
                    never, never, q.QosLiveliness.AUTOMATIC, never, False,
                )  # fmt: skip
                kwargs = {"offered_qos_profiles": [qos]}
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store, **kwargs)
        raw = (
            self.store.serialize_ros1(msg, msgtype)
            if self.ros == 1
            else self.store.serialize_cdr(msg, msgtype)
        )
        self.writer.write(self.conns[topic], int(t * 1e9), raw)

    def image(self, topic: str, t: float, image: np.ndarray, compressed: bool = False) -> None:
        if compressed:
            data = np.frombuffer(cv2.imencode(".png", image)[1].tobytes(), np.uint8)
            msg = self.t["sensor_msgs/msg/CompressedImage"](header=self.header(t), format="png", data=data)
            return self.write(topic, "sensor_msgs/msg/CompressedImage", msg, t)
        h, w = image.shape
        msg = self.t["sensor_msgs/msg/Image"](
            header=self.header(t), height=h, width=w, encoding="mono8", is_bigendian=0, step=w,
            data=np.ascontiguousarray(image).reshape(-1),
        )  # fmt: skip
        self.write(topic, "sensor_msgs/msg/Image", msg, t)

    def pose(self, topic: str, t: float, position, quat_wxyz) -> None:
        m = self.t
        point = m["geometry_msgs/msg/Point"](x=float(position[0]), y=float(position[1]), z=float(position[2]))
        w, x, y, z = (float(v) for v in quat_wxyz)
        pose = m["geometry_msgs/msg/Pose"](
            position=point, orientation=m["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)
        )
        self.write(
            topic,
            "geometry_msgs/msg/PoseStamped",
            m["geometry_msgs/msg/PoseStamped"](header=self.header(t, "world"), pose=pose),
            t,
        )

    def transforms(self, topic: str, t: float, transforms, latched: bool = False) -> None:
        """A tf2_msgs/TFMessage of (parent, child, xyz, quat_wxyz) transforms, each stamped ``t``
        (X_parent = R X_child + xyz); ``latched`` as /tf_static is recorded."""
        if "tf2_msgs/msg/TFMessage" not in self.t:  # not in rosbags' ROS 1 store: a recorded bag has it
            from rosbags.typesys import get_types_from_msg

            msgdef = "geometry_msgs/TransformStamped[] transforms"
            self.store.register(get_types_from_msg(msgdef, "tf2_msgs/msg/TFMessage"))
            self.t = self.store.types
        m = self.t
        stamped = []
        for parent, child, xyz, (w, x, y, z) in transforms:
            transform = m["geometry_msgs/msg/Transform"](
                translation=m["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
                rotation=m["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w)),
            )
            stamped.append(
                m["geometry_msgs/msg/TransformStamped"](
                    header=self.header(t, parent), child_frame_id=child, transform=transform
                )
            )
        msg = m["tf2_msgs/msg/TFMessage"](transforms=stamped)
        self.write(topic, "tf2_msgs/msg/TFMessage", msg, t, latched)

    def camera_info(self, topic: str, t: float, size, k, d, r, p) -> None:
        """A sensor_msgs/CameraInfo (plumb_bob): 3x3 ``k`` and ``r``, 3x4 ``p``, distortion ``d``."""
        names = ("D", "K", "R", "P") if self.ros == 1 else ("d", "k", "r", "p")
        arrays = [np.asarray(a, dtype=np.float64).reshape(-1) for a in (d, k, r, p)]
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        msg = self.t["sensor_msgs/msg/CameraInfo"](
            header=self.header(t), height=int(size[1]), width=int(size[0]), distortion_model="plumb_bob",
            binning_x=0, binning_y=0, roi=roi, **dict(zip(names, arrays, strict=True)),
        )  # fmt: skip
        self.write(topic, "sensor_msgs/msg/CameraInfo", msg, t)
