"""ROS 1 and ROS 2 bags, written with rosbags' writers, read back by ``replay.bag``."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from replay.frames import make_frame, rectified_camera
from swarm.formats.calibration_formats import load_stereo_calibration

pytest.importorskip("rosbags")
from rosbags.typesys import Stores, get_typestore  # noqa: E402

EUROC = Path("/work/shared/data/euroc_v1_01_micro")
if not EUROC.is_dir():
    EUROC = Path(__file__).resolve().parents[2] / "shared" / "data" / "euroc_v1_01_micro"


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

    def write(self, topic: str, msgtype: str, msg, t: float) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
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


@pytest.mark.parametrize("ros", [1, 2])
def test_missing_topic_is_named(tmp_path, ros):
    path = tmp_path / ("b.bag" if ros == 1 else "b2")
    with BagWriter(path, ros) as bag:
        bag.image("/left", 1.0, np.zeros((8, 8), np.uint8))
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    with pytest.raises(
        RecordingError, match=r"topic /right \(right\) is not in the bag \(topics: /left, /pose\)"
    ):
        BagRecording(path, "/left", "/right", "/pose", calibration=object())


def _mission_calibration():
    return load_stereo_calibration(EUROC / "mav0/cam0/sensor.yaml", EUROC / "mav0/cam1/sensor.yaml")


@pytest.mark.skipif(not EUROC.is_dir(), reason=f"the EuRoC excerpt is not at {EUROC}")
@pytest.mark.parametrize("ros", [1, 2])
def test_euroc_written_to_a_bag_gives_the_asl_frames(tmp_path, ros):
    from replay.asl import AslRecording

    asl = AslRecording(EUROC)
    n = 4
    path = tmp_path / ("euroc.bag" if ros == 1 else "euroc")
    gt = np.loadtxt(EUROC / "mav0/cam0_groundtruth/data.csv", delimiter=",", skiprows=1)
    with BagWriter(path, ros) as bag:
        for k, pair in enumerate(asl.pairs(0, n)):
            if k == 2:
                continue  # one right image lost: the pair is dropped and counted
            bag.image("/cam1/image_raw", pair.t, pair.right, compressed=(ros == 2))
        for pair in asl.pairs(0, n):
            bag.image("/cam0/image_raw", pair.t, pair.left)
            row = gt[np.argmin(np.abs(gt[:, 0] * 1e-9 - pair.t))]
            w, x, y, z = row[4:8]
            bag.pose("/cam0/pose", pair.t, row[1:4], (w, -x, -y, -z))  # world-from-camera: conjugate
    rec = BagRecording(path, "/cam0/image_raw", "/cam1/image_raw", "/cam0/pose", _mission_calibration())
    assert len(rec) == n - 1
    assert rec.matched.describe() == f"{n - 1} kept, dropped: 1 no right image within 0.01"
    cam = rectified_camera(rec.calibration)
    want = [p for k, p in enumerate(asl.pairs(0, n)) if k != 2]
    for a, b in zip(rec.pairs(), want, strict=True):
        fa = make_frame("r1", 0, a, rec.calibration, cam)
        fb = make_frame("r1", 0, b, asl.calibration, cam)
        assert fa.t == pytest.approx(fb.t, abs=1e-6)
        assert np.array_equal(fa.left, fb.left) and np.array_equal(fa.right, fb.right)
        assert np.allclose(fa.pose.xyz, fb.pose.xyz) and np.allclose(fa.pose.ypr, fb.pose.ypr, atol=1e-9)
