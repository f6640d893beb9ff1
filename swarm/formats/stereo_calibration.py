"""Stereo calibration files (docs/design.md section 6): a rectified rig or a full OpenCV calibration.

Two YAML forms are accepted; every error names the file and the field.

Rectified rig (images already rectified; pixels, metres)::

    fx: 138.56        # focal lengths in pixels
    fy: 138.56
    cx: 79.5          # principal point of the left (reference) image
    cy: 59.5
    baseline: 0.09    # metres, the right camera is this far to the left camera's right
    cx_right: 79.5    # optional: right principal point (Middlebury's doffs = cx_right - cx)
    width: 160        # optional: image size the numbers belong to
    height: 120

Full OpenCV stereo calibration (as ``cv2.stereoCalibrate`` gives it; ``M1``/``M2`` are
accepted for ``K1``/``K2``, and OpenCV's own FileStorage files load too: ``%YAML:1.0`` with
``!!opencv-matrix`` nodes, XML, gzip; ``swarm.formats.calibration_text``)::

    K1: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    D1: [k1, k2, p1, p2, k3]      # any OpenCV distortion length, or []
    K2: ...
    D2: ...
    R: [[...], [...], [...]]      # or a Rodrigues 3-vector; X2 = R X1 + T
    T: [-0.09, 0, 0]              # metres; the second camera is to the right: T[0] < 0
    image_size: [160, 120]        # width, height (or image_width, image_height)
    alpha: 0                      # optional cv2.stereoRectify free scaling (0: only valid pixels)

The full form is rectified once on load (``cv2.stereoRectify`` with zero disparity at
infinity, then ``cv2.initUndistortRectifyMap``); the rectified ``fx, fy, cx, cy`` come
from P1, ``cx_right`` from P2 and the baseline from -P2[0, 3] / P2[0, 0]. Depth computed
from a rectified pair is in the *rectified* left camera's frame.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import ValidationError

from swarm.formats.calibration_schema import (
    MAX_BASELINE_M,
    OPENCV_DERIVED_KEYS,
    OpenCVFile,
    RectifiedFile,
    format_errors,
    metres_per_unit,
    other_tool_fields,
)
from swarm.formats.calibration_text import read_calibration_yaml
from swarm.formats.errors import CalibrationError


@dataclass(frozen=True, eq=False)
class RectificationMaps:
    """Pixel maps that rectify raw left/right images (``cv2.remap`` form, CV_16SC2 + CV_16UC1)."""

    left: tuple[np.ndarray, np.ndarray]
    right: tuple[np.ndarray, np.ndarray]

    def apply(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified copies of a raw pair (bilinear, black outside the raw images)."""
        out_l = cv2.remap(left, self.left[0], self.left[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        out_r = cv2.remap(
            right, self.right[0], self.right[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
        )
        return out_l, out_r


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """Rectified intrinsics of a stereo pair, plus the maps that rectify raw images if needed.

    ``fx, fy, cx, cy`` (pixels) belong to the rectified left image, ``baseline`` (m) is the
    distance between the optical centres, ``cx_right`` the rectified right principal point
    (None: equal to ``cx``). ``image_size`` is (width, height) when known. ``maps`` is None
    for a rig that is rectified already. ``left_rotation`` (3x3, None = identity) is R1 of
    ``cv2.stereoRectify``: X_rectified = R1 X_raw in optical axes, so a point measured in the
    rectified left camera is R1.T X in the physical left camera. ``source`` names where the
    calibration came from, for messages. ``ndisp`` is a disparity range the file states
    (Middlebury's ``ndisp``), None when it gives none. ``notes`` are remarks for the user,
    e.g. the fields that were read and ignored. ``cameras`` is each raw camera's (K, D, R, P) as a
    ROS CameraInfo holds them (REP-104), when the calibration rectifies raw images (None: a rig
    rectified already, whose CameraInfo is its rectified pinhole); ``fisheye``: their D is the
    equidistant model's (else radial-tangential).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    cx_right: float | None = None
    image_size: tuple[int, int] | None = None
    maps: RectificationMaps | None = None
    left_rotation: np.ndarray | None = None
    source: str = "<calibration>"
    ndisp: int | None = None
    notes: tuple[str, ...] = ()
    cameras: tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]] | None = None
    fisheye: bool = False

    @property
    def disparity_offset(self) -> float:
        """cx_right - cx: add it to a disparity before dividing (Middlebury's ``doffs``)."""
        return 0.0 if self.cx_right is None else float(self.cx_right - self.cx)

    def check_image_size(self, width: int, height: int, what: str = "image") -> None:
        """Raise CalibrationError when a (width, height) image does not match ``image_size``."""
        if self.image_size is not None and (width, height) != tuple(self.image_size):
            w, h = self.image_size
            raise CalibrationError(
                f"{self.source}: image_size: calibration is for {w}x{h} images, {what} is {width}x{height}"
            )

    def print_notes(self) -> None:
        """Print the notes for the user: a ``warning: ...`` note (an uncertain unit) on stderr as
        it is, the others on stdout as ``note: ...``."""
        for note in self.notes:
            if note.startswith("warning:"):
                print(note, file=sys.stderr, flush=True)
            else:
                print(f"note: {note}", flush=True)

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified versions of a raw pair (unchanged when the rig is rectified already)."""
        if self.maps is None:
            return left, right
        return self.maps.apply(left, right)


# -- loading ---------------------------------------------------------------------------------


def load_calibration(path: str | Path) -> StereoCalibration:
    """Read a calibration YAML file (either form); raises CalibrationError naming file and field."""
    path = Path(path)
    data = read_calibration_yaml(path)
    return calibration_from_dict(data, source=str(path))


def calibration_from_dict(
    data: Any,
    source: str = "<calibration>",
    image_size: tuple[int, int] | None = None,
    units: str | None = None,
) -> StereoCalibration:
    """Build a StereoCalibration from the parsed YAML mapping of either form.

    ``image_size`` (width, height) is the images' size, taken for a full calibration that states
    none (OpenCV's ``stereo_calib`` sample writes no ``image_size``), with a note. ``units``
    (``m``, ``cm``, ``mm``; None: metres) is the unit of the file's ``baseline`` or ``T``.
    """
    if not isinstance(data, dict):
        raise CalibrationError(
            f"{source}: expected a mapping of calibration fields, got {type(data).__name__}"
        )
    full = any(k in data for k in ("K1", "M1", "K2", "M2"))
    rectified = any(k in data for k in ("fx", "fy", "baseline"))
    if full and rectified:
        raise CalibrationError(
            f"{source}: give either a rectified rig (fx, fy, cx, cy, baseline) or a full calibration "
            "(K1, D1, K2, D2, R, T, image_size), not both"
        )
    if not (full or rectified):
        raise CalibrationError(
            f"{source}: no calibration found: expected fx, fy, cx, cy, baseline (rectified rig) or "
            "K1, D1, K2, D2, R, T, image_size (full OpenCV calibration)"
        )
    ignored = [k for k in OPENCV_DERIVED_KEYS if k in data] if full else []
    extra = other_tool_fields(data) if full else []
    data = {k: v for k, v in data.items() if k not in ignored and k not in extra}
    if full and ("image_width" in data or "image_height" in data):  # OpenCV's calibration sample's names
        if not ("image_width" in data and "image_height" in data):
            raise CalibrationError(f"{source}: image_width, image_height: give both or neither")
        size = [data.pop("image_width"), data.pop("image_height")]
        if data.setdefault("image_size", size) != size:
            raise CalibrationError(
                f"{source}: image_size: {data['image_size']} but image_width, image_height say {size}"
            )
    size_note = ()
    if full and "image_size" not in data and image_size is not None:
        data["image_size"] = list(image_size)
        size_note = (
            f"{source}: image_size: not in the file, taken from the images ({image_size[0]}x{image_size[1]})",
        )
    try:
        if rectified:
            rig = RectifiedFile.model_validate(data, context={"units": units})
        else:
            cal = OpenCVFile.model_validate(data, context={"units": units})
    except ValidationError as exc:
        raise CalibrationError(format_errors(exc, source)) from None
    if rectified:
        if (rig.width is None) != (rig.height is None):
            raise CalibrationError(f"{source}: width, height: give both or neither")
        size = None if rig.width is None else (rig.width, rig.height)
        return StereoCalibration(
            fx=rig.fx,
            fy=rig.fy,
            cx=rig.cx,
            cy=rig.cy,
            baseline=rig.baseline,
            cx_right=rig.cx_right,
            image_size=size,
            source=source,
        )
    notes = ()
    if ignored:
        notes = (
            f"{source}: {', '.join(ignored)}: ignored; the rectification is recomputed from "
            "K1, D1, K2, D2, R, T with cv2.stereoRectify",
        )
    if extra:
        notes += (f"{source}: {', '.join(extra)}: not calibration fields this reader uses; ignored",)
    return rectify_stereo(
        cal.K1, cal.D1, cal.K2, cal.D2, cal.R, cal.T, cal.image_size, source, cal.alpha, notes + size_note
    )


def rectify_stereo(
    k1: np.ndarray,
    d1: np.ndarray,
    k2: np.ndarray,
    d2: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    size: tuple[int, int],
    source: str = "<calibration>",
    alpha: float = 0.0,
    notes: tuple[str, ...] = (),
    extrinsics: str = "T",
    fisheye: bool = False,
    units: str | None = None,
) -> StereoCalibration:
    """Rectify a raw stereo pair's calibration (OpenCV's X2 = R X1 + T; ``T`` in ``units``,
    ``m``, ``cm`` or ``mm``, None: metres).

    ``k1``, ``k2`` are 3x3 camera matrices, ``d1``, ``d2`` OpenCV distortion vectors
    (radial-tangential), or with ``fisheye`` the four coefficients of the equidistant model
    (``cv2.fisheye``, Kalibr's and ROS's ``equidistant``); ``size`` is (width, height). Raises
    CalibrationError naming ``extrinsics``, the file's field(s) the translation comes from, for a
    baseline in millimetres, vertical or swapped rigs.
    """
    t = np.ascontiguousarray(translation, dtype=np.float64).reshape(3) * metres_per_unit(units)
    if not np.linalg.norm(t) <= MAX_BASELINE_M:
        declared = "" if units is None else f" (read in {units})"
        raise CalibrationError(
            f"{source}: {extrinsics}: the cameras are {np.linalg.norm(t):g} m apart{declared}; must be in "
            "metres (millimetres? --calib-units declares the unit)"
        )
    swapped = "T[0] < 0 with X2 = R X1 + T" if extrinsics == "T" else "are the two cameras swapped?"
    if fisheye:  # cv2.fisheye wants contiguous float64 arrays
        k1, k2, rotation = (np.ascontiguousarray(a, dtype=np.float64) for a in (k1, k2, rotation))
        d1, d2 = (np.asarray(d, dtype=np.float64).reshape(4, 1) for d in (d1, d2))
        r1, r2, p1, p2, _q = cv2.fisheye.stereoRectify(
            k1, d1, k2, d2, size, rotation, t.reshape(3, 1), cv2.CALIB_ZERO_DISPARITY
        )
    else:
        r1, r2, p1, p2, _q, _roi1, _roi2 = cv2.stereoRectify(
            k1, d1, k2, d2, size, rotation, t.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha
        )
    if abs(p2[1, 3]) > abs(p2[0, 3]):
        raise CalibrationError(
            f"{source}: {extrinsics}: the cameras are displaced vertically; only side-by-side rigs work"
        )
    baseline = -p2[0, 3] / p2[0, 0]
    if not baseline > 0:
        raise CalibrationError(
            f"{source}: {extrinsics}: the second camera must be to the right of the first "
            f"({swapped}), got X2 = R X1 + T with T = {t.tolist()}"
        )
    if not all(math.isfinite(v) for v in (p1[0, 0], p1[1, 1], p1[0, 2], p1[1, 2], baseline)):
        raise CalibrationError(f"{source}: K1, K2, R, T: rectification failed (non-finite projection)")
    left = undistort_rectify_map(k1, d1, r1, p1, size, fisheye)
    right = undistort_rectify_map(k2, d2, r2, p2, size, fisheye)
    return StereoCalibration(
        fx=float(p1[0, 0]),
        fy=float(p1[1, 1]),
        cx=float(p1[0, 2]),
        cy=float(p1[1, 2]),
        baseline=float(baseline),
        cx_right=float(p2[0, 2]),
        image_size=size,
        maps=RectificationMaps(left, right),
        left_rotation=np.asarray(r1, dtype=np.float64),
        source=source,
        notes=notes,
        cameras=tuple(
            tuple(np.asarray(a, dtype=np.float64).copy() for a in camera)
            for camera in ((k1, d1, r1, p1), (k2, d2, r2, p2))
        ),
        fisheye=fisheye,
    )


def undistort_rectify_map(
    k: np.ndarray, d: np.ndarray, r: np.ndarray, p: np.ndarray, size: tuple[int, int], fisheye: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's fixed-point remap tables (CV_16SC2) taking a raw image to the rectified camera ``p``
    (3x3 or 3x4) turned by ``r``: ``cv2.initUndistortRectifyMap``, or its ``cv2.fisheye`` form for
    the equidistant model (``d``: 4 coefficients)."""
    k, r, p = (np.ascontiguousarray(a, dtype=np.float64) for a in (k, r, np.asarray(p)[:, :3]))
    if fisheye:
        return cv2.fisheye.initUndistortRectifyMap(
            k, np.asarray(d, np.float64).reshape(4, 1), r, p, size, cv2.CV_16SC2
        )
    return cv2.initUndistortRectifyMap(k, d, r, p, size, cv2.CV_16SC2)
