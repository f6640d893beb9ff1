"""The fields of the two calibration YAML forms, validated (``swarm.formats.stereo_calibration``).

``RectifiedFile`` (a rectified rig) and ``OpenCVFile`` (a full OpenCV stereo calibration) check
each field's shape, sign and units; ``format_errors`` turns pydantic's errors into lines of
``FILE: FIELD: what is wrong``; ``other_tool_fields`` finds the keys calibration tools add
beside the calibration (ignored with a note), telling them from misspelt fields (refused).
"""

from __future__ import annotations

import difflib
from typing import Any

import cv2
import numpy as np
from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    FiniteFloat,
    ValidationError,
    ValidationInfo,
    field_validator,
)

from swarm.formats.errors import CalibrationError

#: A baseline or translation above this many metres is taken for a unit mistake (millimetres).
MAX_BASELINE_M = 5.0
#: The units a calibration's translation may be declared in (``--calib-units``): metres per unit.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def metres_per_unit(units: str | None) -> float:
    """Metres per unit of a declared calibration unit (``m``, ``cm``, ``mm``; None: metres)."""
    if units is None:
        return 1.0
    if units not in UNITS:
        raise CalibrationError(f"calibration units {units!r}: must be one of {', '.join(UNITS)}")
    return UNITS[units]


def _in_metres(value: Any, info: ValidationInfo) -> tuple[Any, Any]:
    """``value`` (a number or array) in metres, by the ``units`` of the validation context, and a
    function of a length (the file's number) saying why it is refused, for messages."""
    units = (info.context or {}).get("units")
    scale = metres_per_unit(units)

    def implausible(length: float) -> str:
        if units in (None, "m"):
            return f"must be in metres, {length:g} m is implausible"
        return f"{length:g} {units} = {length * scale:g} m is implausible"

    return value * scale, implausible


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class RectifiedFile(_Strict):
    fx: FiniteFloat = Field(gt=0)
    fy: FiniteFloat = Field(gt=0)
    cx: FiniteFloat
    cy: FiniteFloat
    baseline: FiniteFloat = Field(gt=0)
    cx_right: FiniteFloat | None = None
    width: int | None = Field(default=None, ge=1)
    height: int | None = Field(default=None, ge=1)

    @field_validator("baseline")
    @classmethod
    def _metres(cls, value: float, info: ValidationInfo) -> float:
        metres, implausible = _in_metres(value, info)
        if metres > MAX_BASELINE_M:
            raise ValueError(f"{implausible(value)} (Middlebury calib.txt gives millimetres)")
        return metres


def _matrix(value: Any, shape: tuple[int, int]) -> np.ndarray:
    if isinstance(value, dict) and {"rows", "cols", "data"} <= set(value):
        rows, cols, data = value["rows"], value["cols"], value["data"]
        count = len(data) if isinstance(data, list) else 1
        if not (isinstance(rows, int) and isinstance(cols, int) and rows * cols == count):
            raise ValueError(f"rows x cols is {rows} x {cols} but data holds {count} numbers")
        value = data
    elif isinstance(value, dict) and "data" in value:  # !!opencv-nd-matrix: sizes, dt, data
        value = value["data"]
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"must be a {shape[0]}x{shape[1]} matrix of numbers") from exc
    if arr.size != shape[0] * shape[1]:
        raise ValueError(f"must be a {shape[0]}x{shape[1]} matrix, got {arr.size} numbers")
    arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise ValueError("holds NaN or inf")
    return arr


def _vector(value: Any, sizes: tuple[int, ...]) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    if value is None:
        value = []
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError("must be a list of numbers") from exc
    if arr.size not in sizes:
        raise ValueError(f"must have {' or '.join(map(str, sizes))} numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("holds NaN or inf")
    return arr


#: Outputs of cv2.stereoCalibrate / cv2.stereoRectify that a full calibration file may carry.
#: They follow from K1, D1, K2, D2, R, T: they are read, and ignored with a note.
OPENCV_DERIVED_KEYS = ("E", "F", "R1", "R2", "P1", "P2", "Q", "roi1", "roi2", "validRoi1", "validRoi2", "rms")


class OpenCVFile(_Strict):
    model_config = ConfigDict(extra="forbid", populate_by_name=True, arbitrary_types_allowed=True)

    K1: Any = Field(validation_alias=AliasChoices("K1", "M1"))
    D1: Any = Field(default=None, validate_default=True)
    K2: Any = Field(validation_alias=AliasChoices("K2", "M2"))
    D2: Any = Field(default=None, validate_default=True)
    R: Any
    T: Any
    image_size: Any
    alpha: FiniteFloat = Field(default=0.0, ge=-1, le=1)

    @field_validator("K1", "K2")
    @classmethod
    def _camera_matrix(cls, value: Any) -> np.ndarray:
        k = _matrix(value, (3, 3))
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise ValueError("focal lengths K[0][0] and K[1][1] must be > 0")
        if not np.allclose(k[2], [0, 0, 1]):
            raise ValueError("last row must be [0, 0, 1]")
        return k

    @field_validator("D1", "D2")
    @classmethod
    def _distortion(cls, value: Any) -> np.ndarray:
        return _vector(value, (0, 4, 5, 8, 12, 14))

    @field_validator("R")
    @classmethod
    def _rotation(cls, value: Any) -> np.ndarray:
        raw = value["data"] if isinstance(value, dict) and "data" in value else value
        try:
            count = np.asarray(raw, dtype=np.float64).size
        except (TypeError, ValueError) as exc:
            raise ValueError("must be a 3x3 rotation matrix or a Rodrigues 3-vector") from exc
        if count == 3:
            rvec = _vector(value, (3,))
            return cv2.Rodrigues(rvec.reshape(3, 1))[0]
        r = _matrix(value, (3, 3))
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-3) or np.linalg.det(r) < 0:
            raise ValueError("must be a rotation matrix (orthonormal, determinant +1)")
        return r

    @field_validator("T")
    @classmethod
    def _translation(cls, value: Any, info: ValidationInfo) -> np.ndarray:
        raw = _vector(value, (3,))
        t, implausible = _in_metres(raw, info)
        if np.linalg.norm(t) > MAX_BASELINE_M:
            raise ValueError(
                f"|T|: {implausible(float(np.linalg.norm(raw)))} (millimetres or centimetres? --calib-units "
                "declares the unit)"
            )
        if np.linalg.norm(t) == 0:
            raise ValueError("must not be zero (the cameras need a baseline)")
        return t

    @field_validator("image_size")
    @classmethod
    def _size(cls, value: Any) -> tuple[int, int]:
        arr = _vector(value, (2,))
        if np.any(arr < 1) or np.any(arr != np.round(arr)):
            raise ValueError("must be [width, height], two positive integers")
        return int(arr[0]), int(arr[1])


#: The fields of a full calibration this reader uses (``image_width`` and ``image_height``
#: stand for ``image_size``).
OPENCV_FIELDS = tuple("K1 M1 D1 K2 M2 D2 R T image_size image_width image_height alpha".split())
#: difflib's similarity above which an unknown key is taken for a misspelt field.
_MISSPELT = 0.75


def other_tool_fields(data: dict) -> list[str]:
    """Keys of a full calibration that are neither used nor derived (``calibration_time``,
    ``avg_reprojection_error``, board sizes: what calibration tools add), to ignore with a note.
    A key that looks like a misspelt field (``alpah``, ``image_sise``) is not among them: the
    validation then refuses it as an unknown field."""
    known = OPENCV_FIELDS + OPENCV_DERIVED_KEYS
    return [
        k
        for k in data
        if k not in known and not difflib.get_close_matches(str(k), known, n=1, cutoff=_MISSPELT)
    ]


#: Every field name of either form, for "did you mean" in an unknown-field error.
_FIELD_NAMES = OPENCV_FIELDS + OPENCV_DERIVED_KEYS + tuple(RectifiedFile.model_fields)


def format_errors(exc: ValidationError, source: str) -> str:
    lines = []
    for err in exc.errors():
        field = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field"
            near = difflib.get_close_matches(field, _FIELD_NAMES, n=1, cutoff=_MISSPELT)
            if near:
                msg += f" (did you mean {near[0]}?)"
        elif err["type"] == "missing":
            msg = "required field is missing"
            if field == "image_size":
                msg += " (add image_size: [width, height], the size of the calibration images)"
            elif field in ("R", "T"):
                msg += " (OpenCV's stereo_calib sample writes R and T to extrinsics.yml: give it too)"
        got = err.get("input")
        shown = "" if isinstance(got, dict | list) or err["type"] == "missing" else f" (got {got!r})"
        lines.append(f"{source}: {field}: {msg}{shown}")
    return "\n".join(lines)


# -- plain field readers (camera_info, Kalibr, Middlebury forms) ----------------------------------


def whole_number(value: Any) -> Any:
    """``value`` as an int when it is a whole float (some tools write ``image_width: 640.0``)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


def numbers(value: Any, count: int | tuple[int, ...], source: str, field: str) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"{source}: {field}: must be a list of numbers") from None
    counts = (count,) if isinstance(count, int) else count
    if arr.size not in counts:
        want = " or ".join(str(c) for c in counts)
        raise CalibrationError(f"{source}: {field}: must have {want} numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{source}: {field}: holds NaN or inf")
    return arr


def rectified_camera_differences(
    left: np.ndarray, right: np.ndarray, tolerance: float
) -> list[tuple[str, float, float]]:
    """The terms of one rectified camera that two camera matrices (3x3 K or 3x4 P, pixels) do not
    share within ``tolerance`` px: (name, left, right) for fx, fy and cy. A rectified pair has one
    focal length and one ``cy``; only ``cx`` may differ."""
    terms = (("fx", (0, 0)), ("fy", (1, 1)), ("cy", (1, 2)))
    return [(name, left[ij], right[ij]) for name, ij in terms if abs(left[ij] - right[ij]) > tolerance]


def field_value(data: dict, source: str, *names: str) -> Any:
    for name in names:
        if name in data:
            return data[name]
    near = difflib.get_close_matches(names[0], [str(k) for k in data], n=1, cutoff=0.75)
    hint = f" (is {near[0]} a misspelling of it?)" if near else ""
    raise CalibrationError(f"{source}: {names[0]}: required field is missing{hint}")


#: The equidistant (Kannala-Brandt) fisheye model's names: ROS's and Kalibr's, OpenCV's, camodocal's
#: (ros2/common_interfaces#160 lists them); four coefficients, rectified with ``cv2.fisheye``.
#: Model names are read in any case.
FISHEYE_MODELS = ("equidistant", "fisheye", "kannala_brandt", "kannala-brandt")


def fisheye_coefficients(value: Any, source: str, field: str) -> np.ndarray:
    """The equidistant model's four coefficients k1..k4. A driver that fills the plumb_bob-sized
    five (the RealSense T265's ROS driver, realsenseai/realsense-ros#1989) has a fifth that means
    nothing: zeros past the fourth are dropped, anything else there is refused."""
    d = numbers(value, tuple(range(4, 15)), source, field)
    if np.any(d[4:]):
        raise CalibrationError(
            f"{source}: {field}: the equidistant (fisheye) model has 4 coefficients k1..k4, got {d.size} "
            f"with non-zero ones past the fourth ({d[4:].tolist()})"
        )
    return d[:4]
