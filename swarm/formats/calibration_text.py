"""Reading a calibration file: its text and its YAML, as users' tools write them.

Every form of ``swarm.formats.stereo_calibration`` and ``swarm.formats.calibration_formats``
is read through here: UTF-8 with or without a byte-order mark (Windows editors write one),
OpenCV FileStorage's ``%YAML:1.0`` header and ``!!opencv-matrix`` (and other ``!!opencv-``)
nodes, FileStorage's XML form (``<opencv_storage>``, read with ``cv2.FileStorage`` into the
same mapping as the YAML form), gzip-compressed files (FileStorage's ``.yml.gz``, ``.xml.gz``),
and the ``---`` separators of a ROS message saved with ``rostopic echo`` / ``ros2 topic echo``.
"""

from __future__ import annotations

import gzip
import zlib
from pathlib import Path
from typing import Any

import cv2
import yaml

from swarm.formats.errors import CalibrationError
from swarm.formats.yaml_file import yaml_problem


def _opencv_node(loader: yaml.SafeLoader, _suffix: str, node: yaml.Node) -> Any:
    """An ``!!opencv-matrix``, ``!!opencv-nd-matrix`` (a 1-D array) or other OpenCV node, untagged."""
    if isinstance(node, yaml.MappingNode):
        return loader.construct_mapping(node, deep=True)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_scalar(node)


class _CalibLoader(yaml.SafeLoader):
    """SafeLoader that also reads OpenCV FileStorage's ``!!opencv-...`` nodes."""


_CalibLoader.add_multi_constructor("tag:yaml.org,2002:opencv-", _opencv_node)


def read_calibration_yaml(path: Path) -> Any:
    """The parsed YAML of a calibration file (OpenCV ``%YAML:1.0`` files with matrices too).

    Raises CalibrationError naming the file when it is missing, unreadable or not YAML.
    """
    text = read_calibration_text(path)
    if text.lstrip().startswith(("<?xml", "<opencv_storage")):
        return _read_filestorage_xml(text, path)
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


def _read_filestorage_xml(text: str, path: Path) -> Any:
    """An OpenCV FileStorage XML file as the mapping its YAML twin parses to (matrices as
    ``{rows, cols, dt, data}``). Raises CalibrationError naming the file when OpenCV cannot read it."""
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # the Python binding wraps a parse error in SystemError
        cause = exc.__cause__ if isinstance(exc.__cause__, cv2.error) else exc
        lines = [line for line in str(cause).splitlines() if "error:" in line] or [str(cause)]
        detail = lines[-1].split("error:", 1)[-1].strip()
        raise CalibrationError(f"{path}: not a readable OpenCV FileStorage XML file ({detail})") from None
    try:
        return _filenode_value(storage.root())
    finally:
        storage.release()


def _filenode_value(node: cv2.FileNode) -> Any:
    if node.isMap():
        return {key: _filenode_value(node.getNode(key)) for key in node.keys()}
    if node.isSeq():
        return [_filenode_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return None


def read_calibration_text(path: Path) -> str:
    """A calibration file's text: UTF-8, a byte-order mark (Windows editors write one) dropped;
    a gzip-compressed file (OpenCV FileStorage writes ``.yml.gz``, ``.xml.gz``) decompressed.

    Raises CalibrationError naming the file when it is missing, unreadable or not UTF-8.
    """
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise CalibrationError(f"{path}: calibration file not found") from None
    except OSError as exc:
        raise CalibrationError(f"{path}: cannot read calibration file ({exc.strerror})") from None
    if raw.startswith(b"\x1f\x8b"):
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as exc:
            raise CalibrationError(f"{path}: a damaged gzip file ({exc})") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CalibrationError(
            f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); save it as UTF-8"
        ) from None
