"""Middlebury's ``calib.txt``: a rectified rig (``cam0``, ``cam1``, ``doffs``, ``baseline`` in
millimetres, ``width``, ``height``, ``ndisp``), as the 2005-2021 stereo datasets give it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from swarm.formats.calibration_schema import (
    MAX_BASELINE_M,
    metres_per_unit,
    numbers,
    rectified_camera_differences,
)
from swarm.formats.calibration_text import read_calibration_text
from swarm.formats.errors import CalibrationError
from swarm.formats.stereo_calibration import StereoCalibration

_MATRIX = re.compile(r"^\[(.*)\]$")


def load_middlebury(path: str | Path, units: str = "mm") -> StereoCalibration:
    """Middlebury 2014 ``calib.txt``: a rectified rig, ``baseline`` in millimetres (the format's
    unit; ``units`` ``m`` or ``cm`` reads a hand-written file in another), ``ndisp`` kept."""
    path = Path(path)
    source = str(path)
    lines = read_calibration_text(path).splitlines()
    values: dict[str, str] = {}
    for line in lines:
        if "=" in line:
            key, value = line.split("=", 1)
            values[key.strip()] = value.strip()

    if "cam0" not in values:
        raise CalibrationError(
            f"{source}: cam0: required field is missing (a .txt calibration is read as a Middlebury "
            "calib.txt, cam0=[f 0 cx; 0 f cy; 0 0 1], or as ROS camera_calibration's ost.txt, an "
            "[image] section then one per camera)"
        )

    def matrix(name: str) -> np.ndarray:
        match = _MATRIX.match(values.get(name, ""))
        if match is None:
            raise CalibrationError(f"{source}: {name}: expected [f 0 cx; 0 f cy; 0 0 1]")
        rows = [r.split() for r in match.group(1).split(";")]
        return numbers(rows if all(len(r) == 3 for r in rows) else [], 9, source, name).reshape(3, 3)

    def number(name: str, default: float | None = None) -> float:
        if name not in values:
            if default is not None:
                return default
            raise CalibrationError(f"{source}: {name}: required field is missing")
        try:
            value = float(values[name])
        except ValueError:
            raise CalibrationError(f"{source}: {name}: not a number (got {values[name]!r})") from None
        if not np.isfinite(value):
            raise CalibrationError(f"{source}: {name}: must be a finite number (got {values[name]!r})")
        return value

    def whole(name: str) -> int:
        value = number(name)
        if not (value == int(value) and value > 0):  # int(): inf is refused as not a number above
            raise CalibrationError(f"{source}: {name}: must be a whole number > 0 (got {values[name]!r})")
        return int(value)

    cam0, cam1 = matrix("cam0"), matrix("cam1")
    _check_rectified(cam0, cam1, source)
    baseline_read = number("baseline")
    if not baseline_read > 0:
        raise CalibrationError(f"{source}: baseline: must be > 0 ({units}), got {baseline_read:g}")
    baseline = baseline_read * metres_per_unit(units)
    if baseline > MAX_BASELINE_M:
        raise CalibrationError(
            f"{source}: baseline: {baseline_read:g} {units} = {baseline:g} m is implausible for a stereo rig"
        )
    doffs = number("doffs", cam1[0, 2] - cam0[0, 2])
    if abs(doffs - (cam1[0, 2] - cam0[0, 2])) > 0.01:
        raise CalibrationError(
            f"{source}: doffs: {doffs:g} is not cam1 cx - cam0 cx = {cam1[0, 2] - cam0[0, 2]:g}"
        )
    size = None
    if "width" in values and "height" in values:
        size = (whole("width"), whole("height"))
    ndisp = whole("ndisp") if "ndisp" in values else None
    return StereoCalibration(
        fx=float(cam0[0, 0]),
        fy=float(cam0[1, 1]),
        cx=float(cam0[0, 2]),
        cy=float(cam0[1, 2]),
        baseline=baseline,
        cx_right=float(cam1[0, 2]),
        image_size=size,
        source=source,
        ndisp=ndisp,
        notes=(f"{source}: baseline {baseline_read:g} {units} read as {baseline:g} m",),
    )


def _check_rectified(cam0: np.ndarray, cam1: np.ndarray, source: str) -> None:
    """A calib.txt describes rectified views: one focal length and one ``cy`` for both (only ``cx``
    differs, by ``doffs``). Two raw cameras' own matrices copied into it (SimpleStereo#26) would
    be read as a rectified rig, silently wrong: refused, naming the numbers that differ."""
    differ = [
        f"{name} {left:g} vs {right:g}"
        for name, left, right in rectified_camera_differences(cam0, cam1, tolerance=0.01)
    ]
    if differ:
        raise CalibrationError(
            f"{source}: cam0, cam1: {', '.join(differ)}; a calib.txt describes rectified views (one f, one "
            "cy), so these look like two raw cameras' matrices: rectify first, or give their OpenCV "
            "stereo calibration (K1 D1 K2 D2 R T) instead"
        )
