"""Stereolabs ZED factory calibration, ``SN<serial>.conf`` (what ``calib.stereolabs.com`` serves and
the ZED SDK keeps in ``/usr/local/zed/settings``), an INI file::

    [LEFT_CAM_HD]          one section per camera and resolution (2K, FHD, HD, VGA; ZED X:
    fx=700.8               FHD1200, SVGA; ...): pixels of that resolution's images
    fy=700.8
    cx=640.5
    cy=360.2
    k1=-0.17               k1 k2 p1 p2 k3, and k4 k5 k6 when the model has them
    ...
    [RIGHT_CAM_HD]
    ...
    [STEREO]
    Baseline=119.9         millimetres: T = [-Baseline, TY, TZ] (X_right = R X_left + T)
    TY=0.02                (or TY_HD, TZ_HD)
    TZ=0.26
    CV_HD=0.0101           R = Rodrigues([RX_HD, CV_HD, RZ_HD]), radians
    RX_HD=0.0039
    RZ_HD=-0.0009

read as Stereolabs' own OpenCV sample (stereolabs/zed-opencv-native) reads it: the images' size
picks the resolution, then the pair is rectified as an OpenCV stereo calibration.
"""

from __future__ import annotations

import configparser
import re
from pathlib import Path

import cv2
import numpy as np

from swarm.formats.calibration_schema import metres_per_unit
from swarm.formats.errors import CalibrationError
from swarm.formats.stereo_calibration import StereoCalibration, rectify_stereo

#: one camera's image size (width, height) of each resolution a ZED .conf names
RESOLUTIONS = {
    "2K": (2208, 1242),
    "FHD": (1920, 1080),
    "FHD1200": (1920, 1200),
    "HD": (1280, 720),
    "SVGA": (960, 600),
    "VGA": (672, 376),
}


def is_zed_conf(text: str) -> bool:
    """Whether a calibration file's text is a ZED ``.conf``: a ``[STEREO]`` and a camera section."""
    return bool(re.search(r"^\s*\[STEREO\]\s*$", text, re.M)) and "[LEFT_CAM_" in text


def load_zed_conf(
    path: Path, text: str, image_size: tuple[int, int] | None, units: str = "mm"
) -> StereoCalibration:
    """The rectified rig of a ZED ``.conf`` at the images' ``image_size`` (width, height of one
    camera). ``units`` is the translation's (the file's millimetres unless declared). Raises
    CalibrationError naming the file and the section or key."""
    source = str(path)
    conf = configparser.ConfigParser()
    try:
        conf.read_string(text, source=source)
    except configparser.Error as exc:
        raise CalibrationError(f"{source}: not a readable ZED .conf ({' '.join(str(exc).split())})") from None
    sizes = {name: size for name, size in RESOLUTIONS.items() if conf.has_section(f"LEFT_CAM_{name}")}
    if image_size is None:
        raise CalibrationError(
            f"{source}: a ZED .conf holds one calibration per resolution; the images' size picks it "
            "(swarm stereo depth and swarm replay bag give it)"
        )
    found = [name for name, size in sizes.items() if size == tuple(image_size)]
    if not found:
        held = ", ".join(f"{name} {w}x{h}" for name, (w, h) in sizes.items()) or "none this reader knows"
        raise CalibrationError(
            f"{source}: no calibration for {image_size[0]}x{image_size[1]} images (the file holds {held})"
        )
    res = found[0]

    def number(section: str, *keys: str, default: float | None = None) -> float:
        for key in keys:
            if conf.has_option(section, key):
                try:
                    value = float(conf.get(section, key))
                except ValueError:
                    raise CalibrationError(
                        f"{source}: [{section}] {key}: not a number ({conf.get(section, key)!r})"
                    ) from None
                if not np.isfinite(value):
                    raise CalibrationError(f"{source}: [{section}] {key}: must be finite")
                return value
        if default is None:
            raise CalibrationError(f"{source}: [{section}] {keys[0]}: required key is missing")
        return default

    def camera(side: str) -> tuple[np.ndarray, np.ndarray]:
        section = f"{side}_CAM_{res}"
        if not conf.has_section(section):
            raise CalibrationError(f"{source}: [{section}]: required section is missing")
        fx, fy, cx, cy = (number(section, key) for key in ("fx", "fy", "cx", "cy"))
        if not (fx > 0 and fy > 0):
            raise CalibrationError(f"{source}: [{section}] fx, fy: focal lengths must be > 0")
        d = [number(section, key, default=0.0) for key in ("k1", "k2", "p1", "p2", "k3")]
        if any(conf.has_option(section, key) for key in ("k4", "k5", "k6")):  # rational model
            d += [number(section, key, default=0.0) for key in ("k4", "k5", "k6")]
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), np.array(d)

    (k1, d1), (k2, d2) = camera("LEFT"), camera("RIGHT")
    stereo = "STEREO"
    baseline = number(stereo, "baseline")
    translation = np.array(
        [
            -baseline,
            number(stereo, f"ty_{res}", "ty", default=0.0),
            number(stereo, f"tz_{res}", "tz", default=0.0),
        ]
    )
    angles = [number(stereo, f"{key}_{res}", default=0.0) for key in ("rx", "cv", "rz")]
    rotation = cv2.Rodrigues(np.array(angles, dtype=np.float64).reshape(3, 1))[0]
    metres = baseline * metres_per_unit(units)
    notes = (f"{source}: [{stereo}] Baseline {baseline:g} {units} read as {metres:g} m (resolution {res})",)
    return rectify_stereo(
        k1, d1, k2, d2, rotation, translation, tuple(image_size), source, notes=notes,
        extrinsics=f"[{stereo}] Baseline, TY, TZ", units=units,
    )  # fmt: skip
