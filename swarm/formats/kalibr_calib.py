"""EuRoC / Kalibr calibrations: a pair of ASL ``sensor.yaml`` (``intrinsics [fu, fv, cu, cv]``,
``distortion_coefficients``, ``resolution``, ``T_BS`` the camera's pose in the body) or one
Kalibr ``camchain.yaml`` (``cam0``, ``cam1`` with ``T_cn_cnm1``, or both cameras' IMU
transforms); radial-tangential or equidistant (fisheye, ``cv2.fisheye``) distortion. Read
through ``swarm.formats.calibration_formats.load_stereo_calibration``; every error names the
file and the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from swarm.formats.calibration_schema import FISHEYE_MODELS, field_value, fisheye_coefficients, numbers
from swarm.formats.calibration_text import read_calibration_yaml
from swarm.formats.errors import CalibrationError
from swarm.formats.stereo_calibration import StereoCalibration, rectify_stereo


@dataclass(frozen=True)
class KalibrCamera:
    """A raw camera: K (3x3), D (radtan, or equidistant with ``fisheye``), size (w, h), and its pose
    ``T_BS`` (4x4) in a body frame."""

    k: np.ndarray
    d: np.ndarray
    size: tuple[int, int]
    body_from_camera: np.ndarray
    source: str
    fisheye: bool = False  # equidistant distortion (4 coefficients), else radial-tangential

    @classmethod
    def from_dict(cls, data: Any, source: str, pose_field: str = "T_BS") -> KalibrCamera:
        if not isinstance(data, dict):
            raise CalibrationError(f"{source}: expected a mapping, got {type(data).__name__}")
        camera_model = str(data.get("camera_model", "pinhole"))
        if camera_model != "pinhole":  # Kalibr's omni, eucm, ds put more numbers in intrinsics
            raise CalibrationError(
                f"{source}: camera_model: {camera_model!r} is not supported (pinhole only)"
            )
        fu, fv, cu, cv = numbers(field_value(data, source, "intrinsics"), 4, source, "intrinsics")
        if fu <= 0 or fv <= 0:
            raise CalibrationError(f"{source}: intrinsics: focal lengths fu, fv must be > 0")
        model = str(data.get("distortion_model", "radial-tangential")).strip().lower()
        fisheye = model in FISHEYE_MODELS
        if model not in ("radial-tangential", "radtan", "plumb_bob", "none") and not fisheye:
            raise CalibrationError(
                f"{source}: distortion_model: {model!r} is not supported (radial-tangential or equidistant)"
            )
        d = field_value(data, source, "distortion_coefficients", "distortion_coeffs")
        field = "distortion_coefficients"
        d = fisheye_coefficients(d, source, field) if fisheye else numbers(d, (0, 4, 5), source, field)
        w, h = numbers(field_value(data, source, "resolution"), 2, source, "resolution")
        if not (w == int(w) and h == int(h) and w > 0 and h > 0):
            raise CalibrationError(
                f"{source}: resolution: must be [width, height], two whole numbers > 0 (got [{w:g}, {h:g}])"
            )
        pose = numbers(field_value(data, source, pose_field), 16, source, pose_field).reshape(4, 4)
        rot = pose[:3, :3]
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-3) or np.linalg.det(rot) < 0:
            raise CalibrationError(f"{source}: {pose_field}: the rotation part is not a rotation matrix")
        k = np.array([[fu, 0, cu], [0, fv, cv], [0, 0, 1]])
        return cls(k, d, (int(w), int(h)), pose, source, fisheye)

    @classmethod
    def load(cls, path: str | Path) -> KalibrCamera:
        path = Path(path)
        return cls.from_dict(read_calibration_yaml(path), str(path))


def stereo_from_kalibr(
    left: KalibrCamera,
    right: KalibrCamera,
    source: str | None = None,
    extrinsics: str = "T_BS",
    units: str | None = None,
) -> StereoCalibration:
    """Rectify a pair given both cameras' poses in one body frame (EuRoC's two ``T_BS``).

    ``source`` and ``extrinsics`` (the field that holds the relative pose) name the pair in errors;
    ``units`` is the translations' unit (``m``, ``cm``, ``mm``; None: metres, as Kalibr writes)."""
    source = source or f"{left.source} + {right.source}"
    if left.size != right.size:
        raise CalibrationError(f"{right.source}: resolution: {right.size}, the left camera is {left.size}")
    if left.fisheye != right.fisheye:
        raise CalibrationError(
            f"{right.source}: distortion_model: one camera is equidistant (fisheye), the other is not"
        )
    right_from_left = np.linalg.inv(right.body_from_camera) @ left.body_from_camera  # X1 = R X0 + T
    return rectify_stereo(
        left.k, left.d, right.k, right.d, right_from_left[:3, :3], right_from_left[:3, 3], left.size, source,
        extrinsics=extrinsics, fisheye=left.fisheye, units=units,
    )  # fmt: skip


def stereo_from_camchain(data: dict, source: str, units: str | None = None) -> StereoCalibration:
    """Kalibr ``camchain.yaml``: ``cam0`` and ``cam1``, the latter with ``T_cn_cnm1`` (X1 = T X0);
    without it, both cameras' ``T_cam_imu`` (Kalibr's camchain-imucam: X_cam = T X_imu) or
    ``T_imu_cam`` (OpenVINS's kalibr_imucam_chain.yaml: X_imu = T X_cam) give the pair's pose."""
    for name in ("cam0", "cam1"):
        if not isinstance(data.get(name), dict):
            raise CalibrationError(f"{source}: {name}: required camera section is missing")
    cam0, cam1 = data["cam0"], data["cam1"]
    if "T_cn_cnm1" in cam1:
        extrinsics = "cam1.T_cn_cnm1"
        right_from_left = _rigid(cam1["T_cn_cnm1"], source, extrinsics)
    elif "T_cam_imu" in cam0 and "T_cam_imu" in cam1:
        extrinsics = "cam0.T_cam_imu, cam1.T_cam_imu"
        imu = [_rigid(c["T_cam_imu"], source, f"cam{n}.T_cam_imu") for n, c in enumerate((cam0, cam1))]
        right_from_left = imu[1] @ np.linalg.inv(imu[0])
    elif "T_imu_cam" in cam0 and "T_imu_cam" in cam1:
        extrinsics = "cam0.T_imu_cam, cam1.T_imu_cam"
        imu = [_rigid(c["T_imu_cam"], source, f"cam{n}.T_imu_cam") for n, c in enumerate((cam0, cam1))]
        right_from_left = np.linalg.inv(imu[1]) @ imu[0]
    else:
        raise CalibrationError(
            f"{source}: cam1.T_cn_cnm1: required field is missing (or T_cam_imu / T_imu_cam in both cameras)"
        )
    left = KalibrCamera.from_dict({**cam0, "T_BS": np.eye(4).tolist()}, f"{source}: cam0")
    right = KalibrCamera.from_dict(
        {**cam1, "T_BS": np.linalg.inv(right_from_left).tolist()}, f"{source}: cam1"
    )
    return stereo_from_kalibr(left, right, source, extrinsics, units)


def _rigid(value: Any, source: str, field: str) -> np.ndarray:
    """A 4x4 rigid transform (rotation, translation, last row 0 0 0 1) from a file's field."""
    t = numbers(value, 16, source, field).reshape(4, 4)
    rot = t[:3, :3]
    if not (
        np.allclose(rot @ rot.T, np.eye(3), atol=1e-3)
        and np.linalg.det(rot) > 0
        and np.allclose(t[3], [0, 0, 0, 1])
    ):
        raise CalibrationError(
            f"{source}: {field}: not a rigid transform (a rotation, a translation, 0 0 0 1)"
        )
    return t
