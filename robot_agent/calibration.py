"""Stereo calibration files: re-exported from ``swarm.formats`` (the replay role reads them too).

``load_stereo_calibration(path, right=None)`` reads every supported form (docs/stereo.md).
"""

from swarm.formats.calibration_formats import (
    CameraInfo,
    KalibrCamera,
    load_middlebury,
    load_stereo_calibration,
    stereo_from_camera_infos,
    stereo_from_kalibr,
)
from swarm.formats.stereo_calibration import (
    CalibrationError,
    RectificationMaps,
    StereoCalibration,
    calibration_from_dict,
    load_calibration,
    rectify_stereo,
)

__all__ = [
    "CalibrationError",
    "CameraInfo",
    "KalibrCamera",
    "RectificationMaps",
    "StereoCalibration",
    "calibration_from_dict",
    "load_calibration",
    "load_middlebury",
    "load_stereo_calibration",
    "rectify_stereo",
    "stereo_from_camera_infos",
    "stereo_from_kalibr",
]
