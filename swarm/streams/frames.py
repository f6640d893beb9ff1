"""From a recorded raw pair and the left camera's pose to the ``robot/<id>/frame`` a driver sends.

The pair is undistorted and rectified with the stereo calibration; the pose published is the
*rectified* left camera's (``replay.poses``); the camera is the rectified intrinsics.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from swarm.formats.stereo_calibration import CalibrationError, StereoCalibration
from swarm.protocol.wire import Camera, Frame
from swarm.streams.poses import wire_pose


@dataclass
class RecordedPair:
    """One stereo pair of a recording: time (s), raw uint8 images, left camera pose (optical)."""

    t: float
    left: np.ndarray
    right: np.ndarray
    position: np.ndarray
    world_R_optical: np.ndarray


def rectified_camera(calib: StereoCalibration) -> Camera:
    """The wire Camera of a calibration's rectified images; refuses a principal-point offset."""
    if calib.image_size is None:
        raise CalibrationError(f"{calib.source}: the image size is unknown (give width and height)")
    if abs(calib.disparity_offset) > 0.01:
        raise CalibrationError(
            f"{calib.source}: the rectified principal points differ by {calib.disparity_offset:g} px; "
            "robot frames carry one cx (rectify with zero disparity at infinity)"
        )
    w, h = calib.image_size
    return Camera(w, h, calib.fx, calib.fy, calib.cx, calib.cy, calib.baseline)


def fit_image_size(calib: StereoCalibration, width: int, height: int, where: str) -> StereoCalibration:
    """The calibration of a recording whose images are ``width`` x ``height`` px: a rectified rig that
    states no size (no rectification maps) takes the images'; one made for another size raises
    CalibrationError naming ``where`` (the images' file or topic) and the calibration's source."""
    if calib.image_size is None and calib.maps is None:
        return dataclasses.replace(calib, image_size=(int(width), int(height)))
    if calib.image_size is not None and (width, height) != tuple(calib.image_size):
        w, h = calib.image_size
        raise CalibrationError(
            f"{where}: images are {width}x{height}, the calibration ({calib.source}) is for {w}x{h}"
        )
    return calib


def to_gray8(image: np.ndarray) -> np.ndarray:
    """A uint8 gray image from gray/BGR, 8 or 16 bit (16 bit keeps the top 8 bits)."""
    import cv2

    image = np.asarray(image)
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.dtype != np.uint8:
        raise ValueError(f"unsupported pixel type {image.dtype}")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return np.ascontiguousarray(image)


def make_frame(robot: str, seq: int, pair: RecordedPair, calib: StereoCalibration, camera: Camera) -> Frame:
    """The frame of one pair: rectified gray images, rectified camera, its pose on the wire."""
    left, right = to_gray8(pair.left), to_gray8(pair.right)
    if left.shape != (camera.height, camera.width) or right.shape != left.shape:
        raise ValueError(
            f"pair at t={pair.t:.3f}: images {left.shape[::-1]} and {right.shape[::-1]}, "
            f"the calibration is for {camera.width}x{camera.height}"
        )
    left, right = calib.rectify(left, right)
    pose = wire_pose(pair.position, pair.world_R_optical, calib.left_rotation)
    return Frame(robot, seq, pair.t, pose, camera, "raw8", left=left, right=right)
