"""Two camera_info that are not one rectified pair: each camera's own monocular calibration with
a Tx written into the right one's P by hand (the shape of the camera_info in
introlab/rtabmap_ros#108; ros-perception/image_pipeline#60 and #446 on calibrating each camera
alone). Before, the pair was read with the left P's fx and each image rectified onto its own rows,
so that matching rows did not line up, silently."""

import pytest
import yaml

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError


def _write(tmp_path, name: str, p: list[float]):
    info = {"image_width": 376, "image_height": 240, "distortion_model": "plumb_bob"}
    info |= {"camera_matrix": [p[0], 0, p[2], 0, p[5], p[6], 0, 0, 1], "distortion_coefficients": [0.0] * 5}
    info |= {"rectification_matrix": [1.0, 0, 0, 0, 1, 0, 0, 0, 1], "projection_matrix": p}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(info))
    return path


def test_two_monocular_calibrations_are_refused_naming_what_differs(tmp_path):
    left = _write(tmp_path, "left", [283.88, 0, 181.98, 0, 0, 282.29, 126.74, 0, 0, 0, 1, 0])
    right = _write(tmp_path, "right", [281.02, 0, 184.10, -281.02 * 0.12, 0, 280.61, 121.30, 0, 0, 0, 1, 0])
    words = r"right.yaml: projection_matrix: fx 281.02 \(left 283.88\), fy .*, cy 121.3 \(left 126.74\)"
    with pytest.raises(CalibrationError, match=words):
        load_stereo_calibration(left, right)


def test_a_rectified_pair_whose_principal_points_differ_in_x_reads(tmp_path):
    left = _write(tmp_path, "left", [283.88, 0, 181.98, 0, 0, 283.88, 126.74, 0, 0, 0, 1, 0])
    right = _write(tmp_path, "right", [283.88, 0, 190.0, -283.88 * 0.12, 0, 283.88, 126.74, 0, 0, 0, 1, 0])
    calib = load_stereo_calibration(left, right)
    assert (calib.baseline, calib.disparity_offset) == pytest.approx((0.12, 190.0 - 181.98))


def test_a_fisheye_pair_whose_p_is_k_times_r_is_refused_naming_it(tmp_path):
    """ros-perception/image_pipeline#626: camera_calibration's fisheye stereo writes P[:3, :3] = K R,
    so each camera's P is its own K turned by its rectification; before, read as a camera matrix."""
    import cv2
    import numpy as np

    k = np.array([[283.88, 0, 181.98], [0, 283.88, 126.74], [0, 0, 1]])
    r = cv2.Rodrigues(np.array([0.01, -0.02, 0.004]))[0]
    p = np.hstack([k @ r, np.zeros((3, 1))]).ravel().tolist()
    left = _write(tmp_path, "left", p)
    right = _write(tmp_path, "right", [283.88, 0, 181.98, -283.88 * 0.12, 0, 283.88, 126.74, 0, 0, 0, 1, 0])
    with pytest.raises(
        CalibrationError, match=r"left.yaml: projection_matrix: its left 3x3 is not a camera matrix"
    ):
        load_stereo_calibration(left, right)
