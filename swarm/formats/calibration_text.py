"""Reading a calibration file: its text and its YAML, as users' tools write them.

Every form of ``swarm.formats.stereo_calibration`` and ``swarm.formats.calibration_formats``
is read through here: UTF-8 with or without a byte-order mark (Windows editors write one),
OpenCV FileStorage's ``%YAML:1.0`` header and ``!!opencv-matrix`` nodes, and the ``---``
separators of a ROS message saved with ``rostopic echo`` / ``ros2 topic echo``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from swarm.formats.errors import CalibrationError
from swarm.formats.yaml_file import yaml_problem


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> dict:
    return loader.construct_mapping(node, deep=True)


class _CalibLoader(yaml.SafeLoader):
    """SafeLoader that also reads OpenCV FileStorage's ``!!opencv-matrix`` nodes."""


_CalibLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)


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
        raise CalibrationError(f"{path}: not valid YAML: {yaml_problem(exc)}") from None

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
