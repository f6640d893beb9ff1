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
accepted for ``K1``/``K2``, and OpenCV's own ``%YAML:1.0`` files with ``!!opencv-matrix``
nodes load too)::

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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from pydantic import AliasChoices, BaseModel, ConfigDict, Field, FiniteFloat, ValidationError, field_validator

from swarm.formats.errors import InputError

#: A baseline or translation above this many metres is taken for a unit mistake (millimetres).
MAX_BASELINE_M = 5.0


class CalibrationError(InputError):
    """An unusable calibration: the message names the file, the field and the problem."""


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
    e.g. the fields that were read and ignored.
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

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified versions of a raw pair (unchanged when the rig is rectified already)."""
        if self.maps is None:
            return left, right
        return self.maps.apply(left, right)


# -- YAML schema -----------------------------------------------------------------------------


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


class _RectifiedFile(_Strict):
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
    def _metres(cls, value: float) -> float:
        if value > MAX_BASELINE_M:
            raise ValueError(
                f"must be in metres, {value:g} m is implausible (Middlebury calib.txt gives millimetres)"
            )
        return value


def _matrix(value: Any, shape: tuple[int, int]) -> np.ndarray:
    if isinstance(value, dict) and {"rows", "cols", "data"} <= set(value):
        value = np.asarray(value["data"], dtype=np.float64).reshape(int(value["rows"]), int(value["cols"]))
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


class _OpenCVFile(_Strict):
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
    def _translation(cls, value: Any) -> np.ndarray:
        t = _vector(value, (3,))
        if np.linalg.norm(t) > MAX_BASELINE_M:
            raise ValueError(f"must be in metres, |T| = {np.linalg.norm(t):g} m is implausible")
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


# -- loading ---------------------------------------------------------------------------------


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> dict:
    return loader.construct_mapping(node, deep=True)


class _CalibLoader(yaml.SafeLoader):
    """SafeLoader that also reads OpenCV FileStorage's ``!!opencv-matrix`` nodes."""


_CalibLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)


def load_calibration(path: str | Path) -> StereoCalibration:
    """Read a calibration YAML file (either form); raises CalibrationError naming file and field."""
    path = Path(path)
    data = read_calibration_yaml(path)
    return calibration_from_dict(data, source=str(path))


def read_calibration_yaml(path: Path) -> Any:
    """The parsed YAML of a calibration file (OpenCV ``%YAML:1.0`` files with matrices too).

    Raises CalibrationError naming the file when it is missing, unreadable or not YAML.
    """
    text = read_calibration_text(path)
    if text.startswith("%YAML:"):  # OpenCV FileStorage header, not valid YAML 1.1
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        documents = [d for d in yaml.load_all(text, Loader=_CalibLoader) if d is not None]
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{path}: not valid YAML ({exc})") from None

    # ``rostopic echo`` / ``ros2 topic echo`` end each message with ``---``: messages that differ
    # only in their header (a camera_info echoed several times) are one calibration.
    def unstamped(d: Any) -> Any:
        return {k: v for k, v in d.items() if k != "header"} if isinstance(d, dict) else d

    if any(unstamped(d) != unstamped(documents[0]) for d in documents[1:]):
        raise CalibrationError(
            f"{path}: holds {len(documents)} different YAML documents (separated by ---); keep one"
        )
    if not documents:
        raise CalibrationError(f"{path}: the file is empty (no YAML mapping in it)")
    return documents[0]


def read_calibration_text(path: Path) -> str:
    """A calibration file's text: UTF-8, a byte-order mark (Windows editors write one) dropped.

    Raises CalibrationError naming the file when it is missing, unreadable or not UTF-8.
    """
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise CalibrationError(f"{path}: calibration file not found") from None
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read calibration file ({exc.strerror})") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CalibrationError(
            f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); save it as UTF-8"
        ) from None


def calibration_from_dict(
    data: Any, source: str = "<calibration>", image_size: tuple[int, int] | None = None
) -> StereoCalibration:
    """Build a StereoCalibration from the parsed YAML mapping of either form.

    ``image_size`` (width, height) is the images' size, taken for a full calibration that states
    none (OpenCV's ``stereo_calib`` sample writes no ``image_size``), with a note.
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
    data = {k: v for k, v in data.items() if k not in ignored}
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
            rig = _RectifiedFile.model_validate(data)
        else:
            cal = _OpenCVFile.model_validate(data)
    except ValidationError as exc:
        raise CalibrationError(_format_errors(exc, source)) from None
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
    return rectify_stereo(
        cal.K1, cal.D1, cal.K2, cal.D2, cal.R, cal.T, cal.image_size, source, cal.alpha, notes + size_note
    )


def _format_errors(exc: ValidationError, source: str) -> str:
    lines = []
    for err in exc.errors():
        field = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field"
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
) -> StereoCalibration:
    """Rectify a raw stereo pair's calibration (OpenCV's X2 = R X1 + T, metres, radtan distortion).

    ``k1``, ``k2`` are 3x3 camera matrices, ``d1``, ``d2`` OpenCV distortion vectors, ``size``
    is (width, height). Raises CalibrationError naming ``extrinsics``, the file's field(s) the
    translation comes from, for a baseline in millimetres, vertical or swapped rigs.
    """
    t = np.asarray(translation, dtype=np.float64).reshape(3)
    if not np.linalg.norm(t) <= MAX_BASELINE_M:
        raise CalibrationError(
            f"{source}: {extrinsics}: the cameras are {np.linalg.norm(t):g} m apart; must be in metres "
            "(millimetres?)"
        )
    swapped = "T[0] < 0 with X2 = R X1 + T" if extrinsics == "T" else "are the two cameras swapped?"
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
    left = cv2.initUndistortRectifyMap(k1, d1, r1, p1, size, cv2.CV_16SC2)
    right = cv2.initUndistortRectifyMap(k2, d2, r2, p2, size, cv2.CV_16SC2)
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
    )
