"""Equidistant (fisheye) cameras: Kalibr camchains and ROS camera_info pairs of the model, under
any of its names, rectify a fisheye pair (dots seen by both cameras land on one row)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError
from tests.support.calibration_files import _matrix

# -- equidistant (fisheye) cameras ----------------------------------------------------------------
FISH_SIZE = (400, 300)


FISH_K = np.array([[190.0, 0, 201.0], [0, 191.0, 148.0], [0, 0, 1]])


FISH_D = np.array([0.02, -0.01, 0.004, -0.001])  # k1..k4 of the equidistant model


FISH_R = cv2.Rodrigues(np.array([0.01, 0.02, -0.01]))[0]


FISH_T = np.array([-0.1, 0.001, 0.002])


def _dots_seen_by(calib, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rectified (u, v) of each 3-D point (left raw camera frame) in the left and right images:
    a dot drawn where cv2.fisheye projects it in each raw image, rectified by ``calib``, found
    again as the brightest spot's centroid."""
    rvec2 = cv2.Rodrigues(FISH_R)[0]
    found = []
    for side, (rvec, tvec) in enumerate(((np.zeros(3), np.zeros(3)), (rvec2.ravel(), FISH_T))):
        raw_uv = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), rvec, tvec, FISH_K, FISH_D)[0].reshape(
            -1, 2
        )
        spots = []
        for u, v in raw_uv:
            image = np.zeros(FISH_SIZE[::-1], np.uint8)
            cv2.circle(image, (round(u * 16), round(v * 16)), 3 * 16, 255, -1, cv2.LINE_AA, shift=4)
            rect = calib.rectify(image, image)[side]
            ys, xs = np.nonzero(rect > 128)
            w = rect[ys, xs].astype(np.float64)
            spots.append((np.sum(xs * w) / w.sum(), np.sum(ys * w) / w.sum()))
        found.append(np.array(spots))
    return found[0], found[1]


def _check_fisheye_rectification(calib) -> None:
    points = np.array([[x, y, z] for z in (1.0, 2.5) for x in (-0.4, 0.0, 0.4) for y in (-0.2, 0.25)])
    left, right = _dots_seen_by(calib, points)
    assert calib.baseline == pytest.approx(np.linalg.norm(FISH_T), rel=1e-6)
    np.testing.assert_allclose(left[:, 1], right[:, 1], atol=0.3)  # same row after rectification
    # depth along the rectified axis: the point turned into the rectified left camera
    z = (points @ calib.left_rotation.T)[:, 2]
    disparity = left[:, 0] - right[:, 0] + (calib.cx_right - calib.cx)
    np.testing.assert_allclose(disparity, calib.fx * calib.baseline / z, rtol=0.02, atol=0.3)


def test_kalibr_equidistant_camchain_rectifies_a_fisheye_pair(tmp_path):
    """Kalibr's equidistant model (TUM-VI, RealSense T265 calibrations): rectified with cv2.fisheye,
    3-D points land on one row in both images at the disparity f b / Z."""
    right_from_left = np.eye(4)
    right_from_left[:3, :3], right_from_left[:3, 3] = FISH_R, FISH_T
    cam = {"camera_model": "pinhole", "distortion_model": "equidistant", "resolution": list(FISH_SIZE)}
    cam |= {"intrinsics": [190.0, 191.0, 201.0, 148.0], "distortion_coeffs": FISH_D.tolist()}
    chain = {"cam0": dict(cam), "cam1": dict(cam, T_cn_cnm1=right_from_left.tolist())}
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(chain))
    _check_fisheye_rectification(load_stereo_calibration(tmp_path / "camchain.yaml"))


def test_ros_camera_info_pair_with_the_equidistant_model_rectifies_a_fisheye_pair(tmp_path):
    r1, r2, p1, p2, _q = cv2.fisheye.stereoRectify(
        FISH_K, FISH_D, FISH_K, FISH_D, FISH_SIZE, FISH_R, FISH_T.reshape(3, 1), cv2.CALIB_ZERO_DISPARITY
    )
    paths = []
    for name, r, p in (("left", r1, p1), ("right", r2, p2)):
        info = {"image_width": FISH_SIZE[0], "image_height": FISH_SIZE[1], "distortion_model": "equidistant"}
        info |= {"camera_matrix": _matrix(FISH_K), "distortion_coefficients": _matrix(FISH_D)}
        info |= {"rectification_matrix": _matrix(r), "projection_matrix": _matrix(p)}
        paths.append(tmp_path / f"{name}.yaml")
        paths[-1].write_text(yaml.safe_dump(info))
    _check_fisheye_rectification(load_stereo_calibration(*paths))
    # the RealSense T265 driver's five, the fifth 0 (realsenseai/realsense-ros#1989): the same rig
    info["distortion_coefficients"] = _matrix(np.r_[FISH_D, 0.0])
    paths[1].write_text(yaml.safe_dump(info))
    _check_fisheye_rectification(load_stereo_calibration(*paths))
    info["distortion_coefficients"] = _matrix(np.r_[FISH_D, 0.01])
    paths[1].write_text(yaml.safe_dump(info))
    with pytest.raises(
        CalibrationError,
        match=r"right.yaml: distortion_coefficients: the equidistant \(fisheye\) model has 4 coefficients "
        r"k1..k4, got 5 with non-zero ones past the fourth \(\[0.01\]\)",
    ):
        load_stereo_calibration(*paths)


@pytest.mark.parametrize("model", ["kannala_brandt", "Kannala-Brandt", "FISHEYE", " equidistant"])
def test_the_fisheye_model_s_other_names_and_cases_are_read(tmp_path, model):
    """ros2/common_interfaces#160: the equidistant model is Kalibr's 'equidistant', OpenCV's
    'fisheye', camodocal's 'kannala-brandt'; a driver writing another of them, or capitals, was
    refused as an unsupported model."""
    r1, r2, p1, p2, _q = cv2.fisheye.stereoRectify(
        FISH_K, FISH_D, FISH_K, FISH_D, FISH_SIZE, FISH_R, FISH_T.reshape(3, 1), cv2.CALIB_ZERO_DISPARITY
    )
    paths = []
    for name, r, p in (("left", r1, p1), ("right", r2, p2)):
        info = {"image_width": FISH_SIZE[0], "image_height": FISH_SIZE[1], "distortion_model": model}
        info |= {"camera_matrix": _matrix(FISH_K), "distortion_coefficients": _matrix(FISH_D)}
        info |= {"rectification_matrix": _matrix(r), "projection_matrix": _matrix(p)}
        paths.append(tmp_path / f"{name}.yaml")
        paths[-1].write_text(yaml.safe_dump(info))
    _check_fisheye_rectification(load_stereo_calibration(*paths))
