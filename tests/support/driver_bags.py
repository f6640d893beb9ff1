"""Bags as real camera drivers write them (encodings, stamps, pose and info topics), for the replay tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.formats.stereo_calibration import StereoCalibration
from tests.support.rosbag_writer import BagWriter

H, W = 12, 16


# a rectified rig that states no image size: it takes the images' (these tests read images, stamps, poses)
CALIB = StereoCalibration(100.0, 100.0, 8.0, 6.0, 0.1, source="rectified test rig")


class DriverBag(BagWriter):
    """``BagWriter`` with the raw messages of real drivers: any Image encoding, /tf, Odometry."""

    def raw_image(self, topic, t, encoding, data, width=W, height=H, step=None, bigendian=0, log_t=None):
        data = np.frombuffer(bytes(data), np.uint8)
        step = len(data) // height if step is None else step
        msg = self.t["sensor_msgs/msg/Image"](
            header=self.header(t), height=height, width=width, encoding=encoding,
            is_bigendian=bigendian, step=step, data=data,
        )  # fmt: skip
        self.write(topic, "sensor_msgs/msg/Image", msg, t if log_t is None else log_t)

    def _transform(self, t, parent, child, xyz):
        m = self.t
        transform = m["geometry_msgs/msg/Transform"](
            translation=m["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
            rotation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        return m["geometry_msgs/msg/TransformStamped"](
            header=self.header(t, parent), child_frame_id=child, transform=transform
        )

    def tf(self, topic, t, transforms) -> None:
        """A tf2_msgs/TFMessage of several (parent, child, xyz) transforms (tf2_ros's broadcaster)."""
        if "tf2_msgs/msg/TFMessage" not in self.t:  # not in rosbags' ROS 1 store: a recorded bag has it
            from rosbags.typesys import get_types_from_msg

            msgdef = "geometry_msgs/TransformStamped[] transforms"
            self.store.register(get_types_from_msg(msgdef, "tf2_msgs/msg/TFMessage"))
            self.t = self.store.types
        msg = self.t["tf2_msgs/msg/TFMessage"](transforms=[self._transform(t, *tf) for tf in transforms])
        self.write(topic, "tf2_msgs/msg/TFMessage", msg, t)

    def transform_stamped(self, topic, t, child, xyz) -> None:
        """A geometry_msgs/TransformStamped, as vicon_bridge publishes a tracked subject."""
        self.write(topic, "geometry_msgs/msg/TransformStamped", self._transform(t, "world", child, xyz), t)

    def odometry(self, topic, t, child, xyz) -> None:
        m = self.t
        point = m["geometry_msgs/msg/Point"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))
        pose = m["geometry_msgs/msg/Pose"](
            position=point, orientation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        )
        zero = m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        twist = m["geometry_msgs/msg/Twist"](linear=zero, angular=zero)
        msg = m["nav_msgs/msg/Odometry"](
            header=self.header(t, "odom"), child_frame_id=child,
            pose=m["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=m["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )  # fmt: skip
        self.write(topic, "nav_msgs/msg/Odometry", msg, t)

    def camera_info_binned(self, topic, t, size, k, d, r, p, binning=0, roi=(0, 0, 0, 0)) -> None:
        """A CameraInfo as REP-104 has it: the calibrated (full) size, K and P, the binning and ROI."""
        names = ("D", "K", "R", "P") if self.ros == 1 else ("d", "k", "r", "p")
        arrays = [np.asarray(a, dtype=np.float64).reshape(-1) for a in (d, k, r, p)]
        x, y, w, h = roi
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=x, y_offset=y, height=h, width=w, do_rectify=False
        )
        msg = self.t["sensor_msgs/msg/CameraInfo"](
            header=self.header(t), height=int(size[1]), width=int(size[0]), distortion_model="plumb_bob",
            binning_x=binning, binning_y=binning, roi=roi, **dict(zip(names, arrays, strict=True)),
        )  # fmt: skip
        self.write(topic, "sensor_msgs/msg/CameraInfo", msg, t)

    def empty_topic(self, topic: str, msgtype: str) -> None:
        self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)


def _bag(tmp_path: Path, ros: int, name: str = "b") -> Path:
    return tmp_path / (f"{name}.bag" if ros == 1 else f"{name}-ros2")


def _colour() -> np.ndarray:
    """A smooth BGR picture (so that a demosaiced mosaic matches its gray closely)."""
    yy, xx = np.mgrid[0:H, 0:W]
    return np.dstack([40 + 6 * xx, 60 + 9 * yy, 220 - 5 * xx - 3 * yy]).astype(np.uint8)


def gray_pattern(k: int) -> np.ndarray:
    return ((np.arange(H * W).reshape(H, W) * 7 + 31 * k) % 256).astype(np.uint8)


def record_stereo(bag: DriverBag, times, left="/left", right="/right", pose="/pose") -> None:
    for k, t in enumerate(times):
        bag.image(left, t, gray_pattern(k))
        bag.image(right, t, gray_pattern(k))
        bag.pose(pose, t, [0, 0, 1], [1, 0, 0, 0])
