"""Stereo calibrations in the forms users have, read into a ``StereoCalibration``.

* ROS ``camera_info`` (one per camera; ``swarm.formats.camera_info_ini`` for the INI form and
  ``camera_calibration``'s two-camera ``ost.txt``): the YAML of ``camera_calibration_parsers``
  (``image_width``, ``camera_matrix``, ``distortion_coefficients``, ``rectification_matrix``,
  ``projection_matrix``) or the fields of a ``sensor_msgs/CameraInfo`` message (``k d r p``,
  ROS 1's ``K D R P``). The right camera's ``P[0][3]`` is ``-fx * baseline``.
* EuRoC / Kalibr (``swarm.formats.kalibr_calib``): a pair of ASL ``sensor.yaml`` files or one
  Kalibr ``camchain.yaml``; radial-tangential or equidistant (fisheye) distortion.
* Stereolabs ZED ``SN<serial>.conf`` (``swarm.formats.zed_conf``): both cameras per resolution, mm.
* Luxonis OAK (DepthAI) calibration JSON (``swarm.formats.depthai_calib``): every camera, cm.
* Middlebury ``calib.txt`` (``cam0=[f 0 cx; 0 f cy; 0 0 1]``, ``doffs``, ``baseline`` in mm,
  ``ndisp``): a rectified rig.
* OpenCV files (``K1 D1 K2 D2 R T``, plus ``E F R1 R2 P1 P2 Q``): ``swarm.formats.stereo_calibration``.

``load_stereo_calibration(path, right)`` tells the forms apart by their fields. Every error
names the file and the field.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from swarm.formats.calibration_schema import (
    FISHEYE_MODELS,
    MAX_BASELINE_M,
    field_value,
    fisheye_coefficients,
    metres_per_unit,
    numbers,
    whole_number,
)
from swarm.formats.calibration_text import read_calibration_text, read_calibration_yaml
from swarm.formats.camera_info_checks import (
    binning,
    check_camera_matrix_form,
    check_one_rectified_camera,
    rectified_defaults,
    refuse_region_of_interest,
)
from swarm.formats.camera_info_ini import camera_info_ini, is_camera_info_ini
from swarm.formats.depthai_calib import is_depthai_calibration, stereo_from_depthai
from swarm.formats.kalibr_calib import KalibrCamera, stereo_from_camchain, stereo_from_kalibr
from swarm.formats.middlebury_calib import load_middlebury
from swarm.formats.stereo_calibration import (
    CalibrationError,
    RectificationMaps,
    StereoCalibration,
    calibration_from_dict,
    undistort_rectify_map,
)
from swarm.formats.zed_conf import is_zed_conf, load_zed_conf

#: ROS distortion models OpenCV's pinhole model reads as they are.
PINHOLE_MODELS = ("plumb_bob", "rational_polynomial", "radtan", "radial-tangential", "none", "")
#: A camera_info pair whose baseline comes out shorter (m) wrote the baseline alone in P[0][3].
MIN_BASELINE_M = 0.003


def _read_yaml(path: Path) -> Any:
    return read_calibration_yaml(path)


# -- ROS camera_info -----------------------------------------------------------------------


@dataclass(frozen=True)
class CameraInfo:
    """One camera's ROS calibration: size, K (3x3), D, R (3x3), P (3x4), distortion model.

    Of the images as published: a binned camera's (``binning_x``, ``binning_y`` > 1; REP-104
    keeps the full sensor's size, K and P in the message) are scaled to its binned images; a
    region of interest (``roi``) is refused."""

    width: int
    height: int
    k: np.ndarray
    d: np.ndarray
    r: np.ndarray
    p: np.ndarray
    distortion_model: str
    source: str

    @classmethod
    def from_dict(cls, data: Any, source: str) -> CameraInfo:
        """From a camera_info YAML mapping or a CameraInfo message's fields (ROS 1 or 2 names)."""
        if not isinstance(data, dict):
            raise CalibrationError(f"{source}: expected a camera_info mapping, got {type(data).__name__}")
        width = whole_number(field_value(data, source, "image_width", "width"))
        height = whole_number(field_value(data, source, "image_height", "height"))
        if not (isinstance(width, int) and isinstance(height, int) and width > 0 and height > 0):
            raise CalibrationError(
                f"{source}: image_width, image_height: must be positive integers (got {width!r}, {height!r})"
            )
        model = str(data.get("distortion_model", "plumb_bob") or "").strip().lower()
        if model not in PINHOLE_MODELS + FISHEYE_MODELS:
            raise CalibrationError(
                f"{source}: distortion_model: {model!r} is not supported "
                f"(use one of plumb_bob, rational_polynomial, equidistant)"
            )
        k = numbers(field_value(data, source, "camera_matrix", "k", "K"), 9, source, "camera_matrix").reshape(
            3, 3
        )
        d = field_value(data, source, "distortion_coefficients", "d", "D")
        if model in FISHEYE_MODELS:
            d = fisheye_coefficients(d, source, "distortion_coefficients")
        else:
            d = numbers(d, (0, 4, 5, 8, 12, 14), source, "distortion_coefficients")
        r = numbers(
            data.get("rectification_matrix", data.get("r", data.get("R", np.eye(3)))),
            9,
            source,
            "rectification_matrix",
        )
        if not any(key in data for key in ("projection_matrix", "p", "P")) and "distortion_model" not in data:
            raise CalibrationError(  # OpenCV's calibration sample (ros-perception/image_common#27)
                f"{source}: projection_matrix: required field is missing; a single-camera OpenCV "
                "calibration (camera_matrix, distortion_coefficients) holds no stereo extrinsics: give a "
                "stereo calibration (K1 D1 K2 D2 R T) or each camera's ROS camera_info"
            )
        p = numbers(field_value(data, source, "projection_matrix", "p", "P"), 12, source, "projection_matrix")
        p = p.reshape(3, 4)
        k, r = rectified_defaults(k, d, r.reshape(3, 3), p, source)
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise CalibrationError(f"{source}: camera_matrix: focal lengths must be > 0")
        if p[0, 0] <= 0 or p[1, 1] <= 0:
            raise CalibrationError(f"{source}: projection_matrix: focal lengths must be > 0")
        check_camera_matrix_form(p, source)
        refuse_region_of_interest(data.get("roi"), width, height, source)
        bx, by = (binning(data, name, source) for name in ("binning_x", "binning_y"))
        if (bx, by) != (1, 1):  # REP-104: K, P and the size are the full sensor's
            scale = np.diag([1.0 / bx, 1.0 / by, 1.0])
            k, p = scale @ k, scale @ p
            width, height = width // bx, height // by
        return cls(int(width), int(height), k, d, r, p, model, source)

    @classmethod
    def load(cls, path: str | Path) -> CameraInfo:
        """One camera's camera_info file: YAML, or the INI form (``camera_calibration_parsers``)."""
        path = Path(path)
        cameras = _ini_cameras(path)
        if cameras is None:
            return cls.from_dict(_read_yaml(path), str(path))
        if len(cameras) != 1:
            raise CalibrationError(f"{path}: holds {len(cameras)} cameras; give it alone (--calib)")
        return cls.from_dict(cameras[0][1], f"{path}: [{cameras[0][0]}]")


def _ini_cameras(path: Path) -> list[tuple[str, dict]] | None:
    """The cameras of a camera_info INI file or ``ost.txt``, None for a file of another form."""
    text = read_calibration_text(path)
    return camera_info_ini(text, str(path)) if is_camera_info_ini(text) else None


def stereo_from_camera_infos(
    left: CameraInfo, right: CameraInfo, units: str | None = None
) -> StereoCalibration:
    """A StereoCalibration from the two cameras' camera_info (REP-104: images rectified by R, P;
    ``P[0][3]`` in pixels x metres, or x ``units``, ``m``, ``cm``, ``mm``)."""
    source = f"{left.source} + {right.source}"
    if (left.width, left.height) != (right.width, right.height):
        raise CalibrationError(
            f"{right.source}: image_width, image_height: {right.width}x{right.height}, "
            f"the left camera is {left.width}x{left.height}"
        )
    check_one_rectified_camera(left.p, right.p, right.source)
    # Tx = P[0][3] = -fx * (the camera's x in the pair's reference camera): 0 for the reference,
    # which is the left camera for ROS camera_calibration and the right one for OAK cameras
    # (depthai-ros#369); either way the right camera's Tx is the left's minus fx * baseline
    tx_left, tx_right = left.p[0, 3], right.p[0, 3]
    baseline = (tx_left - tx_right) / right.p[0, 0] * metres_per_unit(units)
    if not baseline > 0:
        if tx_left < 0 or tx_right > 0:
            which, tx = (left, tx_left) if tx_left < 0 else (right, tx_right)
            raise CalibrationError(
                f"{which.source}: projection_matrix: P[0][3] = {tx:g} puts the right camera to the left of "
                "the left one: are --calib-left and --calib-right swapped?"
            )
        raise CalibrationError(
            f"{right.source}: projection_matrix: P[0][3] = -fx * baseline must be < 0 for the right camera, "
            f"got {tx_right:g} (a camera_info of a single camera has 0 there)"
        )
    if baseline > MAX_BASELINE_M:
        raise CalibrationError(
            f"{right.source}: projection_matrix: baseline {baseline:g} m is implausible (millimetres?)"
        )
    if baseline < MIN_BASELINE_M:
        raise CalibrationError(
            f"{right.source}: projection_matrix: P[0][3] = {tx_right:g} gives a baseline of "
            f"{baseline * 1e3:.3g} mm; P[0][3] is -fx * baseline (pixels x metres), not the baseline alone"
        )
    size = (left.width, left.height)
    rectified = all(
        not np.any(info.d) and np.allclose(info.r, np.eye(3)) and np.allclose(info.k, info.p[:, :3])
        for info in (left, right)
    )
    maps = None
    cameras = (left, right)
    if not rectified:
        maps = RectificationMaps(
            *(
                undistort_rectify_map(c.k, c.d, c.r, c.p, size, c.distortion_model in FISHEYE_MODELS)
                for c in (left, right)
            )
        )
    return StereoCalibration(
        fx=float(left.p[0, 0]),
        fy=float(left.p[1, 1]),
        cx=float(left.p[0, 2]),
        cy=float(left.p[1, 2]),
        baseline=float(baseline),
        cx_right=float(right.p[0, 2]),
        image_size=size,
        maps=maps,
        left_rotation=None if rectified else left.r.copy(),
        source=source,
        cameras=None
        if rectified
        else tuple((c.k.copy(), c.d.copy(), c.r.copy(), c.p.copy()) for c in cameras),
        fisheye=left.distortion_model in FISHEYE_MODELS,
    )


# -- one entry point -------------------------------------------------------------------------


def _is_camera_info(data: Any) -> bool:
    """camera_calibration's YAML, or a CameraInfo message as ``rostopic echo`` (``K``, ``P``) or
    ``ros2 topic echo`` (``k``, ``p``) print it."""
    if not isinstance(data, dict):
        return False
    return (
        "projection_matrix" in data
        or "camera_matrix" in data
        or {"k", "p"} <= set(data)
        or {"K", "P"} <= set(data)
    )


def load_stereo_calibration(
    path: str | Path,
    right: str | Path | None = None,
    image_size: tuple[int, int] | None = None,
    units: str | None = None,
) -> StereoCalibration:
    """Read any supported form: ``right`` is the second file of two-file forms (camera_info and
    EuRoC sensor.yaml: the right camera's; OpenCV's ``stereo_calib`` sample: ``extrinsics.yml``
    beside ``intrinsics.yml``). ``image_size`` (width, height) is the images' size, used by an
    OpenCV calibration that states none. ``units`` (``m``, ``cm``, ``mm``) declares the unit of
    the file's translation or baseline; None takes each form's own (metres; Middlebury's
    millimetres) and adds a warning to ``notes`` when the cameras come out between
    ``UNCERTAIN_BASELINE_M`` and 5 m apart, where a rig in centimetres would read too. Raises
    CalibrationError naming the file and field."""
    metres_per_unit(units)  # an unknown unit is refused before any file is read
    path = Path(path)
    if is_zed_conf(read_calibration_text(path)):  # Stereolabs' factory file: both cameras, mm
        if right is not None:
            raise CalibrationError(f"{right}: a ZED .conf ({path}) describes both cameras; give it alone")
        return load_zed_conf(path, read_calibration_text(path), image_size, units or "mm")
    calib = _load_any(path, right, image_size, units)
    if units is None and UNCERTAIN_BASELINE_M <= calib.baseline and not _states_its_unit(path):
        calib = replace(calib, notes=(*calib.notes, _uncertain_unit_warning(calib)))
    return calib


#: A baseline read as metres from this long up to 5 m is also what a rig of 1-5 cm written in
#: centimetres gives; such a reading is warned of (stereo rigs this wide are rare, ones that
#: narrow are common: RealSense D4xx 5 cm, phone modules 1-2 cm).
UNCERTAIN_BASELINE_M = 1.0


def _uncertain_unit_warning(calib: StereoCalibration) -> str:
    metres = calib.baseline
    return (
        f"warning: {calib.source}: the cameras come out {metres:.4g} m apart, reading its numbers as "
        f"metres; a rig {metres:.4g} cm apart written in centimetres reads the same. If the file is "
        "in centimetres or millimetres, say so: --calib-units cm (or mm)"
    )


def _states_its_unit(path: Path) -> bool:
    """Whether a calibration file's form fixes its unit (Middlebury's mm, DepthAI's cm)."""
    if _is_middlebury(path):
        return True
    try:
        return _ini_cameras(path) is None and is_depthai_calibration(_read_yaml(path))
    except CalibrationError:
        return False


def _is_middlebury(path: Path) -> bool:
    """A Middlebury calib.txt: any ``.txt`` or ``cam0=`` text but ROS camera_calibration's ost.txt."""
    if _ini_cameras(path) is not None:
        return False
    return path.suffix == ".txt" or read_calibration_text(path).lstrip().startswith("cam0=")


def _load_any(
    path: Path, right: str | Path | None, image_size: tuple[int, int] | None, units: str | None
) -> StereoCalibration:
    cameras = _ini_cameras(path)
    if cameras is not None:  # camera_info INI: one camera, or ROS camera_calibration's stereo ost.txt
        if len(cameras) == 2 and right is None:
            (left_name, left), (right_name, right_info) = cameras
            return stereo_from_camera_infos(
                CameraInfo.from_dict(left, f"{path}: [{left_name}]"),
                CameraInfo.from_dict(right_info, f"{path}: [{right_name}]"),
                units,
            )
        if len(cameras) == 2:
            raise CalibrationError(f"{right}: {path} holds both cameras (ost.txt); give it alone")
        if right is None:
            raise CalibrationError(
                f"{path}: a camera_info INI file describes one camera; give the right camera's too "
                "(--calib-left LEFT.ini --calib-right RIGHT.ini)"
            )
        return stereo_from_camera_infos(CameraInfo.load(path), CameraInfo.load(right), units)
    if _is_middlebury(path):
        if right is not None:
            raise CalibrationError(f"{right}: a Middlebury calib.txt describes both cameras; give it alone")
        return load_middlebury(path, units or "mm")
    data = _read_yaml(path)
    if is_depthai_calibration(data):  # an OAK camera's calibration JSON: both cameras, cm
        if right is not None:
            raise CalibrationError(
                f"{right}: {path} (DepthAI calibration) describes both cameras; give it alone"
            )
        return stereo_from_depthai(data, str(path), image_size, units or "cm")
    if _is_camera_info(data):
        if right is None:
            raise CalibrationError(
                f"{path}: a ROS camera_info describes one camera; give the right camera's too "
                "(--calib-left LEFT.yaml --calib-right RIGHT.yaml)"
            )
        return stereo_from_camera_infos(CameraInfo.from_dict(data, str(path)), CameraInfo.load(right), units)
    if isinstance(data, dict) and "T_BS" in data:
        if right is None:
            raise CalibrationError(
                f"{path}: an EuRoC/Kalibr sensor.yaml describes one camera; give cam1's sensor.yaml too"
            )
        left_camera, right_camera = KalibrCamera.from_dict(data, str(path)), KalibrCamera.load(right)
        return stereo_from_kalibr(left_camera, right_camera, units=units)
    if isinstance(data, dict) and "cam0" in data and "cam1" in data:
        return stereo_from_camchain(data, str(path), units)
    if right is not None:
        other = _read_yaml(Path(right))
        if _opencv_halves(data, other):  # stereo_calib's intrinsics.yml + extrinsics.yml
            return calibration_from_dict({**data, **other}, f"{path} + {right}", image_size, units)
        raise CalibrationError(f"{right}: {path} describes both cameras; give it alone")
    return calibration_from_dict(data, str(path), image_size, units)


def _opencv_halves(a: Any, b: Any) -> bool:
    """Whether two mappings are the two files of OpenCV's stereo_calib sample: the camera
    matrices (``M1 D1 M2 D2``) in one, ``R T`` (with ``R1 R2 P1 P2 Q``) in the other."""
    if not (isinstance(a, dict) and isinstance(b, dict)):
        return False

    def cameras(d: dict) -> bool:
        return any(k in d for k in ("K1", "M1")) and "T" not in d

    def extrinsics(d: dict) -> bool:
        return {"R", "T"} <= set(d) and not any(k in d for k in ("K1", "M1", "K2", "M2"))

    return (cameras(a) and extrinsics(b)) or (cameras(b) and extrinsics(a))
