"""Checks and defaults of one ROS camera_info and of a camera_info pair, for
``swarm.formats.calibration_formats.CameraInfo`` and ``stereo_from_camera_infos``: binning,
region of interest, fields drivers leave unset (K, R all zero), the two P of one rectified camera.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarm.formats.calibration_schema import rectified_camera_differences, whole_number
from swarm.formats.errors import CalibrationError


def rectified_defaults(
    k: np.ndarray, d: np.ndarray, r: np.ndarray, p: np.ndarray, source: str
) -> tuple[np.ndarray, np.ndarray]:
    """K and R of a CameraInfo as its drivers mean them when they leave them unset: R all zero
    (zed-ros-wrapper#126, depthai-ros#58) is no rotation, the identity; K all zero with no
    distortion (depthai-ros#598: a rectified stereo pair's info) is P's left 3x3, the images being
    rectified already. Any other R that is not a rotation is refused naming it."""
    if not np.any(r):
        r = np.eye(3)
    elif not (np.allclose(r @ r.T, np.eye(3), atol=1e-3) and np.linalg.det(r) > 0):
        raise CalibrationError(
            f"{source}: rectification_matrix: not a rotation matrix (orthonormal, determinant +1)"
        )
    if not np.any(k) and not np.any(d) and np.all(np.diag(p)[:2] > 0):
        k = p[:, :3].copy()
    return k, r


def binning(data: dict, name: str, source: str) -> int:
    """``binning_x`` / ``binning_y`` of a CameraInfo: 0 and 1 both mean none (REP-104)."""
    value = whole_number(data.get(name, 0))
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise CalibrationError(f"{source}: {name}: must be a whole number >= 0 (got {value!r})")
    return max(value, 1)


def refuse_region_of_interest(roi: Any, width: int, height: int, source: str) -> None:
    """A CameraInfo ``roi`` other than none (all zero) or the whole image is refused: its images
    are a crop of the calibrated ones."""
    if roi is None:
        return
    if not isinstance(roi, dict):
        raise CalibrationError(f"{source}: roi: expected x_offset, y_offset, width, height (got {roi!r})")
    x, y, w, h = (whole_number(roi.get(key, 0)) for key in ("x_offset", "y_offset", "width", "height"))
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (x, y, w, h)):
        raise CalibrationError(f"{source}: roi: x_offset, y_offset, width, height must be whole numbers")
    if (x or y) or (w, h) not in ((0, 0), (width, height)):
        raise CalibrationError(
            f"{source}: roi: images of a region of interest ({w}x{h} at {x}, {y} of {width}x{height}) "
            "are not supported"
        )


def check_one_rectified_camera(left_p: np.ndarray, right_p: np.ndarray, right_source: str) -> None:
    """The two P (3x4) of a stereo pair describe one rectified camera (cv2.stereoRectify's P1, P2): the
    same fx, fy and cy (cx may differ). Two monocular calibrations' own P, with a Tx written in by
    hand, would rectify the images onto rows that do not line up: refused naming what differs."""
    differ = [
        f"{name} {right:g} (left {left:g})"
        for name, left, right in rectified_camera_differences(left_p, right_p, tolerance=0.05)
    ]
    if differ:
        raise CalibrationError(
            f"{right_source}: projection_matrix: {', '.join(differ)}: the two P of a stereo pair share "
            "fx, fy and cy (one rectified camera); these look like two monocular calibrations: "
            "calibrate the pair together (ROS camera_calibration with two cameras, cv2.stereoCalibrate)"
        )


def check_camera_matrix_form(p: np.ndarray, source: str) -> None:
    """P's left 3x3 is the rectified camera's matrix, ``[fx s cx; 0 fy cy; 0 0 1]``. Some ROS
    camera_calibration releases write K R there for a fisheye pair (image_pipeline#626: each camera's
    own K turned by its R, so the two P differ): the rectified camera is lost, refused naming it."""
    if not (abs(p[1, 0]) <= 1e-6 * p[1, 1] and np.allclose(p[2, :3], [0, 0, 1], atol=1e-6)):
        raise CalibrationError(
            f"{source}: projection_matrix: its left 3x3 is not a camera matrix [fx 0 cx; 0 fy cy; 0 0 1] "
            f"(third row {np.round(p[2, :3], 6).tolist()}); ROS camera_calibration writes K R there for a "
            "fisheye pair: give the pair's Kalibr camchain or OpenCV calibration instead"
        )
