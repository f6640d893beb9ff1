"""Luxonis OAK (DepthAI) calibration JSON (``eepromToJsonFile``), the file OAK owners have: the
stereo pair's extrinsics in **centimetres** (X_to = R X + t, ``toCameraSocket``), 14 distortion
coefficients, intrinsics at the calibration size (luxonis/depthai-ros#369 and #598 show the
same camera's CameraInfo). Before, refused as "no calibration found"."""

import json

import cv2
import numpy as np
import pytest

from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import CalibrationError

R = cv2.Rodrigues(np.array([0.004, -0.008, 0.0025]))[0]
T_CM = np.array([-7.581, -0.0006, 0.0406])
K_LEFT = np.array([[799.74, 0, 662.93], [0, 799.38, 382.24], [0, 0, 1]])
K_RIGHT = np.array([[797.20, 0, 650.11], [0, 797.05, 396.52], [0, 0, 1]])
D_LEFT = np.array([-3.2, 10.1, 0.0004, -0.0003, -6.1, -3.3, 10.4, -6.3, 0, 0, 0, 0, 0, 0])
D_RIGHT = np.array([-2.9, 9.5, 0.0002, 0.0001, -5.8, -3.0, 9.8, -6.0, 0, 0, 0, 0, 0, 0])


def _camera(k, d, extrinsics) -> dict:
    return {"cameraType": 0, "width": 1280, "height": 800, "intrinsicMatrix": k.tolist(),
            "distortionCoeff": d.tolist(), "extrinsics": extrinsics, "specHfovDeg": 71.86}  # fmt: skip


def _calibration(chain: str) -> dict:
    """The pair's extrinsics as an OAK-D writes them (left -> right), or both cameras -> RGB."""
    to_right = {"rotationMatrix": R.tolist(), "toCameraSocket": 2,
                "translation": dict(zip("xyz", T_CM.tolist(), strict=True))}  # fmt: skip
    none = {"rotationMatrix": np.zeros((3, 3)).tolist(), "toCameraSocket": -1, "translation": {}}
    if chain == "left->right":
        left_ext, right_ext = to_right, none
    else:  # both cameras' extrinsics to the RGB camera (socket 0), the pair's pose through it
        rgb_from_right = np.eye(4)
        rgb_from_right[:3, 3] = [3.79, 0.1, -0.2]
        right_from_left = np.eye(4)
        right_from_left[:3, :3], right_from_left[:3, 3] = R, T_CM
        rgb_from_left = rgb_from_right @ right_from_left

        def ext(m):
            return {"rotationMatrix": m[:3, :3].tolist(), "toCameraSocket": 0,
                    "translation": dict(zip("xyz", m[:3, 3].tolist(), strict=True))}  # fmt: skip

        left_ext, right_ext = ext(rgb_from_left), ext(rgb_from_right)
    rgb = _camera(np.array([[1500.0, 0, 960], [0, 1500, 540], [0, 0, 1]]), np.zeros(14), none)
    rgb |= {"width": 1920, "height": 1080}
    left, right = _camera(K_LEFT, D_LEFT, left_ext), _camera(K_RIGHT, D_RIGHT, right_ext)
    return {
        "batchName": "", "boardName": "OAK-D", "version": 7,
        "cameraData": [[0, rgb], [1, left], [2, right]],
        "stereoRectificationData": {"leftCameraSocket": 1, "rightCameraSocket": 2},
    }  # fmt: skip


def _expected(scale: float) -> tuple[float, float, float]:
    size = (int(1280 * scale), int(800 * scale))
    k1, k2 = (np.diag([scale, scale, 1.0]) @ k for k in (K_LEFT, K_RIGHT))
    _r1, _r2, p1, p2, *_ = cv2.stereoRectify(
        k1, D_LEFT, k2, D_RIGHT, size, R, (T_CM / 100).reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    return p1[0, 0], p1[0, 2], -p2[0, 3] / p2[0, 0]


@pytest.mark.parametrize(
    ("chain", "size"), [("left->right", None), ("left->right", (640, 400)), ("both->rgb", None)]
)
def test_a_depthai_calibration_gives_the_pair_in_metres(tmp_path, chain, size):
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(_calibration(chain)))
    calib = load_stereo_calibration(path, image_size=size)
    want = _expected(0.5 if size else 1.0)
    assert (calib.fx, calib.cx, calib.baseline) == pytest.approx(want, rel=1e-6)
    assert calib.baseline == pytest.approx(0.0758, abs=2e-4)  # 7.58 cm, not 7.58 m
    assert not [note for note in calib.notes if note.startswith("warning")]


def test_images_of_another_shape_are_refused_naming_the_camera(tmp_path):
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(_calibration("left->right")))
    with pytest.raises(
        CalibrationError, match=r"calib.json: cameraData\[1\]: calibrated at 1280x800; the images"
    ):
        load_stereo_calibration(path, image_size=(1280, 720))
