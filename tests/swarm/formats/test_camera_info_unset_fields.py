"""camera_info whose drivers leave K or R unset (all zeros), as the public reports show them:
stereolabs/zed-ros-wrapper#126 and luxonis/depthai-ros#58 (R all zero), luxonis/depthai-ros#598
(a rectified pair's info: K all zero, D zero, P set). Before, an all-zero R rectified every image
to black (silently), and a zero K refused a pair whose P says all there is to know."""

from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError
from swarm.streams.image_messages import camera_info

W, H, F, B = 64, 48, 70.0, 0.12
K = [F, 0, 32.0, 0, F, 24.0, 0, 0, 1]
ZERO, EYE = [0.0] * 9, np.eye(3).ravel().tolist()
P_LEFT = [F, 0, 32.0, 0, 0, F, 24.0, 0, 0, 0, 1, 0]
P_RIGHT = [F, 0, 32.0, -F * B, 0, F, 24.0, 0, 0, 0, 1, 0]


def _pair(tmp_path, k, r, d=(0.0,) * 5):
    paths = []
    for name, p in (("left", P_LEFT), ("right", P_RIGHT)):
        info = {"image_width": W, "image_height": H, "distortion_model": "plumb_bob"}
        info |= {"camera_matrix": list(k), "distortion_coefficients": list(d)}
        info |= {"rectification_matrix": list(r), "projection_matrix": p}
        paths.append(tmp_path / f"{name}.yaml")
        paths[-1].write_text(yaml.safe_dump(info))
    return load_stereo_calibration(*paths)


def _image() -> np.ndarray:
    return (np.arange(H * W).reshape(H, W) * 5 % 256).astype(np.uint8)


def test_an_unset_rectification_matrix_is_no_rotation(tmp_path):
    calib = _pair(tmp_path, K, ZERO)  # ZED's rectified images: D 0, R 0
    assert (calib.baseline, calib.fx) == pytest.approx((B, F))
    left, _right = calib.rectify(_image(), _image())
    assert np.array_equal(left, _image())  # before: all black
    distortion = (-0.1, 0.01, 0.0, 0.0, 0.0)
    unset = _pair(tmp_path, K, ZERO, distortion).rectify(_image(), _image())
    identity = _pair(tmp_path, K, EYE, distortion).rectify(_image(), _image())
    assert all(np.array_equal(a, b) for a, b in zip(unset, identity, strict=True))


def test_an_unset_camera_matrix_of_rectified_images_is_their_projection(tmp_path):
    calib = _pair(tmp_path, ZERO, EYE)  # depthai-ros#598
    assert (calib.baseline, calib.fx, calib.cx, calib.maps) == (pytest.approx(B), F, 32.0, None)
    with pytest.raises(CalibrationError, match=r"left.yaml: camera_matrix: focal lengths must be > 0"):
        _pair(tmp_path, ZERO, EYE, (-0.1, 0.01, 0.0, 0.0, 0.0))  # distorted images need their K


def test_a_rectification_matrix_that_is_not_a_rotation_is_refused_naming_it(tmp_path):
    with pytest.raises(CalibrationError, match=r"left.yaml: rectification_matrix: not a rotation matrix"):
        _pair(tmp_path, K, [2.0] + EYE[1:])


def test_a_camera_info_topic_reads_the_same():
    msg = SimpleNamespace(
        width=W, height=H, distortion_model="plumb_bob", k=ZERO, d=[0.0] * 5, r=ZERO, p=P_RIGHT,
        binning_x=0, binning_y=0, roi=SimpleNamespace(x_offset=0, y_offset=0, width=0, height=0),
    )  # fmt: skip
    info = camera_info(msg, "/right/camera_info")
    assert np.array_equal(info.r, np.eye(3)) and np.array_equal(
        info.k, np.asarray(P_RIGHT).reshape(3, 4)[:, :3]
    )


def test_a_pair_whose_reference_is_the_right_camera_gives_the_same_rig(tmp_path):
    """depthai-ros#369: an OAK camera's left P[0][3] is +fx * baseline and the right one's 0 (the
    right camera is the pair's reference); before, refused as a swapped pair."""
    reference = _pair(tmp_path, K, EYE)
    for name, p in (("left", [F, 0, 32.0, F * B, 0, F, 24.0, 0, 0, 0, 1, 0]), ("right", P_LEFT)):
        info = yaml.safe_load((tmp_path / f"{name}.yaml").read_text())
        info["projection_matrix"] = p
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(info))
    calib = load_stereo_calibration(tmp_path / "left.yaml", tmp_path / "right.yaml")
    assert (calib.baseline, calib.fx, calib.cx, calib.cx_right) == pytest.approx(
        (reference.baseline, reference.fx, reference.cx, reference.cx_right)
    )
    with pytest.raises(
        CalibrationError, match=r"left.yaml: projection_matrix: P\[0\]\[3\] = 8.4 puts .* swapped"
    ):
        load_stereo_calibration(tmp_path / "right.yaml", tmp_path / "left.yaml")
