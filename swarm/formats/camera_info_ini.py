"""ROS camera_info in the INI form of ``camera_calibration_parsers`` (``.ini``), and the ``ost.txt``
that ROS ``camera_calibration`` writes beside its YAML: one block per camera::

    # oST version 5.0 parameters

    [image]

    width
    640

    height
    480

    [narrow_stereo/left]

    camera matrix
    500.000000 0.000000 320.000000
    ...
    distortion
    0.100000 -0.050000 0.001000 0.000500 0.000000

    rectification
    ... 3 rows ...

    projection
    ... 3 rows of 4 ...

A stereo calibration's ``ost.txt`` holds two such blocks, the left camera's then the right's.
The distortion model is not written: 8 or more coefficients are ``rational_polynomial``, fewer
``plumb_bob``, as the parsers read them. Each camera becomes the mapping of the YAML form, for
``CameraInfo.from_dict``.
"""

from __future__ import annotations

import re

from swarm.formats.errors import CalibrationError

_SECTION = re.compile(r"^\s*\[([^\]]+)\]\s*$")
_KEYS = {"width": "image_width", "height": "image_height", "camera matrix": "camera_matrix",
         "distortion": "distortion_coefficients", "rectification": "rectification_matrix",
         "projection": "projection_matrix"}  # fmt: skip


def is_camera_info_ini(text: str) -> bool:
    """Whether a calibration file's text is in this form (it has an ``[image]`` section)."""
    return any(_SECTION.match(line) and line.strip() == "[image]" for line in text.splitlines())


def camera_info_ini(text: str, source: str) -> list[tuple[str, dict]]:
    """(camera name, camera_info mapping) of each camera section, in file order.

    Raises CalibrationError naming ``source`` and the section and key for an unknown key, a
    number that is not one, or a camera section before any ``[image]``."""
    cameras: list[tuple[str, dict]] = []
    size: dict[str, list[float]] = {}
    section, key = None, None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        match = _SECTION.match(line)
        if match:
            section, key = match.group(1).strip(), None
            if section == "image":
                size = {}
            elif not size:
                raise CalibrationError(f"{source}: [{section}]: no [image] section (width, height) before it")
            else:
                cameras.append((section, {**size, "distortion_model": None}))
            continue
        if section is None:
            raise CalibrationError(f"{source}: line {number}: {line[:40]!r} before any [section]")
        if line.lower() in _KEYS:
            key = _KEYS[line.lower()]
            (size if section == "image" else cameras[-1][1])[key] = []
            continue
        if key is None:
            raise CalibrationError(f"{source}: [{section}]: line {number}: {line[:40]!r} is not a key")
        try:
            values = [float(word) for word in line.split()]
        except ValueError:
            raise CalibrationError(
                f"{source}: [{section}]: {key}: line {number}: not numbers ({line[:40]!r})"
            ) from None
        (size if section == "image" else cameras[-1][1])[key] += values
    for _name, camera in cameras:
        for field in ("image_width", "image_height"):
            value = camera.get(field)
            camera[field] = value[0] if isinstance(value, list) and len(value) == 1 else value
        count = len(camera.get("distortion_coefficients") or [])
        camera["distortion_model"] = "rational_polynomial" if count >= 8 else "plumb_bob"
    return cameras
