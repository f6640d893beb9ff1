"""A rectified stereo rig's calibration (K, D, R, T, size) and the EuRoC cam0/cam1 sensor.yaml
files, written as the calibration tests read them: the rig as a ROS camera_info pair
(:func:`camera_infos`) and matrices as an OpenCV FileStorage YAML (:func:`opencv_storage`)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

SIZE = (320, 240)


K1 = np.array([[300.0, 0, 161.0], [0, 301.0, 118.0], [0, 0, 1]])


K2 = np.array([[302.0, 0, 158.0], [0, 300.0, 121.0], [0, 0, 1]])


D1 = np.array([-0.2, 0.05, 0.001, -0.0005, 0.0])


D2 = np.array([-0.21, 0.06, 0.0, 0.001, 0.0])


R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]


def _matrix(a: np.ndarray) -> dict:
    a = np.atleast_2d(a)
    return {"rows": a.shape[0], "cols": a.shape[1], "data": a.ravel().tolist()}


EUROC_CAM0 = """%YAML:1.0
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375]
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""


EUROC_CAM1 = """%YAML:1.0
T_BS:
  cols: 4
  rows: 4
  data: [0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556,
         0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024,
        -0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038,
         0.0, 0.0, 0.0, 1.0]
resolution: [752, 480]
camera_model: pinhole
intrinsics: [457.587, 456.134, 379.999, 255.238]
distortion_model: radial-tangential
distortion_coefficients: [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]
"""


#: The right camera's translation from the left (m).
T = np.array([-0.12, 0.002, 0.001])


def camera_infos(tmp_path: Path) -> list[Path]:
    """The rig as ``left.yaml`` and ``right.yaml`` camera_info files in ``tmp_path`` (plumb_bob,
    rectified by ``cv2.stereoRectify`` with zero disparity)."""
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        K1, D1, K2, D2, SIZE, R, T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    paths = []
    for name, k, d, r, p in (("left", K1, D1, r1, p1), ("right", K2, D2, r2, p2)):
        info = {
            "image_width": SIZE[0],
            "image_height": SIZE[1],
            "camera_name": name,
            "camera_matrix": _matrix(k),
            "distortion_model": "plumb_bob",
            "distortion_coefficients": _matrix(d),
            "rectification_matrix": _matrix(r),
            "projection_matrix": _matrix(p),
        }
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(info))
        paths.append(path)
    return paths


def opencv_storage(mats: dict) -> str:
    """An OpenCV FileStorage YAML (``%YAML:1.0``, ``---``, ``!!opencv-matrix`` nodes, data on
    several lines) as ``cv::FileStorage`` writes it."""
    lines = ["%YAML:1.0", "---"]
    for name, m in mats.items():
        m = np.atleast_2d(m)
        values = [f"{v:.16e}" for v in m.ravel()]
        data = ",\n       ".join(", ".join(values[i : i + 3]) for i in range(0, len(values), 3))
        lines.append(f"{name}: !!opencv-matrix\n   rows: {m.shape[0]}\n   cols: {m.shape[1]}\n   dt: d")
        lines.append(f"   data: [ {data} ]")
    return "\n".join(lines) + "\n"
