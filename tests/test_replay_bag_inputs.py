"""Bags as real drivers write them, read by ``replay.bag``: encodings, stamps, pose and info topics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording

pytest.importorskip("rosbags")
from tests.rosbag_writer import BagWriter  # noqa: E402

H, W = 12, 16
CALIB = object()  # a calibration given: these tests read images, stamps and poses only


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

    def empty_topic(self, topic: str, msgtype: str) -> None:
        self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)


def _bag(tmp_path: Path, ros: int, name: str = "b") -> Path:
    return tmp_path / (f"{name}.bag" if ros == 1 else f"{name}-ros2")


def _gray(k: int) -> np.ndarray:
    return ((np.arange(H * W).reshape(H, W) * 7 + 31 * k) % 256).astype(np.uint8)


def _stereo(bag: DriverBag, times, left="/left", right="/right", pose="/pose") -> None:
    for k, t in enumerate(times):
        bag.image(left, t, _gray(k))
        bag.image(right, t, _gray(k))
        bag.pose(pose, t, [0, 0, 1], [1, 0, 0, 0])


@pytest.mark.parametrize("ros", [1, 2])
def test_a_topic_of_the_wrong_type_is_named_with_the_types_read(tmp_path, ros):
    """--left on a PoseStamped, --pose on an Image, --left-info on an Image: named, never a traceback."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        _stereo(bag, [1.0, 1.05])
        bag.image("/cam0/image_raw", 1.0, _gray(0))
    images = r"sensor_msgs/Image, sensor_msgs/CompressedImage"
    with pytest.raises(RecordingError, match=rf"topic /pose \(left\) is a geometry_msgs/PoseStamped; "
                       rf"the left topic must be one of {images}"):  # fmt: skip
        BagRecording(path, "/pose", "/right", "/cam0/image_raw", CALIB)
    with pytest.raises(RecordingError, match=r"topic /cam0/image_raw \(pose\) is a sensor_msgs/Image; "
                       r"the pose topic must be one of geometry_msgs/PoseStamped"):  # fmt: skip
        BagRecording(path, "/left", "/right", "/cam0/image_raw", CALIB)
    with pytest.raises(RecordingError, match=r"topic /left \(left_info\) is a sensor_msgs/Image; "
                       r"the left_info topic must be one of sensor_msgs/CameraInfo"):  # fmt: skip
        BagRecording(path, "/cam0/image_raw", "/right", "/pose", None, "/left", "/right")
    with pytest.raises(RecordingError, match=r"topic /left is given as both left and right"):
        BagRecording(path, "/left", "/left", "/pose", CALIB)
