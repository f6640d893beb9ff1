"""The bundled EuRoC pairs written as a ROS bag, with their camera_info."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from tests.support.paths import TEST_DATA
from tests.support.rosbag_writer import BagWriter

EUROC = TEST_DATA / "euroc_mini"  # four real pairs (its README)


def _euroc_camera_infos():
    """Both cameras' CameraInfo (K, D, R, P) as ROS's stereo calibration writes them: rectified with
    OpenCV from the two sensor.yaml (T_C1C0 = inv(T_BS1) T_BS0, zero disparity at infinity)."""
    from swarm.formats.calibration_formats import KalibrCamera

    left = KalibrCamera.load(EUROC / "mav0/cam0/sensor.yaml")
    right = KalibrCamera.load(EUROC / "mav0/cam1/sensor.yaml")
    c1_from_c0 = np.linalg.inv(right.body_from_camera) @ left.body_from_camera
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        left.k, left.d, right.k, right.d, left.size, c1_from_c0[:3, :3], c1_from_c0[:3, 3].reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
    )  # fmt: skip
    return left.size, (left.k, left.d, r1, p1), (right.k, right.d, r2, p2)


def _write_euroc_bag(path: Path, ros: int) -> None:
    """The shipped EuRoC pairs as a bag: mono8 Images, the left camera's PoseStamped, CameraInfos."""
    from replay.asl import AslRecording

    asl = AslRecording(EUROC)
    size, left_info, right_info = _euroc_camera_infos()
    gt = np.loadtxt(EUROC / "mav0/cam0_groundtruth/data.csv", delimiter=",", skiprows=1)
    with BagWriter(path, ros) as bag:
        for k, pair in enumerate(asl.pairs()):
            if k == 0:
                bag.camera_info("/cam0/camera_info", pair.t, size, *left_info)
                bag.camera_info("/cam1/camera_info", pair.t, size, *right_info)
            bag.image("/cam0/image_raw", pair.t, pair.left)
            bag.image("/cam1/image_raw", pair.t, pair.right)
            row = gt[np.argmin(np.abs(gt[:, 0] * 1e-9 - pair.t))]
            w, x, y, z = row[4:8]
            bag.pose("/cam0/pose", pair.t, row[1:4], (w, -x, -y, -z))  # world-from-camera: conjugate
