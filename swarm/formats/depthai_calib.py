"""Luxonis OAK (DepthAI) calibration JSON, as ``CalibrationHandler.eepromToJsonFile`` writes it::

    {"cameraData": [[1, {"width": 1280, "height": 800,
                         "intrinsicMatrix": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                         "distortionCoeff": [14 numbers, OpenCV's order],
                         "cameraType": 0,               # 0 perspective, 1 fisheye
                         "extrinsics": {"rotationMatrix": [[...]], "toCameraSocket": 2,
                                        "translation": {"x": -7.5, "y": 0, "z": 0}}}],
                    [2, {...}], ...],
     "stereoRectificationData": {"leftCameraSocket": 1, "rightCameraSocket": 2, ...}, ...}

Each camera's extrinsics take its points into the ``toCameraSocket`` camera's frame
(X_to = R X + t), translations in **centimetres**; a camera with ``toCameraSocket`` -1 ends the
chain. The stereo pair is ``stereoRectificationData``'s left and right sockets (default 1 and 2,
CAM_B and CAM_C); the pair's pose follows from both cameras' chains, then it is rectified as an
OpenCV calibration. Intrinsics are for ``width`` x ``height``; images scaled down from that
size (same aspect) scale them, as DepthAI's ``getCameraIntrinsics`` does.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from swarm.formats.calibration_schema import numbers
from swarm.formats.errors import CalibrationError
from swarm.formats.stereo_calibration import StereoCalibration, rectify_stereo


def is_depthai_calibration(data: Any) -> bool:
    """Whether a parsed JSON/YAML document is a DepthAI calibration (a ``cameraData`` list)."""
    return isinstance(data, dict) and isinstance(data.get("cameraData"), list)


def stereo_from_depthai(
    data: dict, source: str, image_size: tuple[int, int] | None, units: str = "cm"
) -> StereoCalibration:
    """The rectified rig of a DepthAI calibration's stereo pair, at the images' ``image_size``
    (None: the file's). ``units``: the translations' (centimetres unless declared). Raises
    CalibrationError naming the file and the camera's socket and field."""
    cameras: dict[int, dict] = {}
    for entry in data["cameraData"]:
        if not (isinstance(entry, list) and len(entry) == 2 and isinstance(entry[1], dict)):
            raise CalibrationError(
                f"{source}: cameraData: expected [socket, {{camera}}] pairs, got {entry!r:.50}"
            )
        cameras[int(entry[0])] = entry[1]
    rect = data.get("stereoRectificationData") or {}
    left_socket = int(rect.get("leftCameraSocket", 1))
    right_socket = int(rect.get("rightCameraSocket", 2))
    for socket in (left_socket, right_socket):
        if socket not in cameras:
            raise CalibrationError(f"{source}: cameraData: no camera at socket {socket} (the stereo pair's)")
    left, right = (_camera(cameras, s, source, image_size) for s in (left_socket, right_socket))
    if left[3] != right[3]:
        raise CalibrationError(
            f"{source}: cameraData[{right_socket}]: cameraType differs from the left camera's"
        )
    root_from_left = _to_chain_end(cameras, left_socket, source)
    root_from_right = _to_chain_end(cameras, right_socket, source)
    if root_from_left[1] != root_from_right[1]:
        raise CalibrationError(
            f"{source}: extrinsics: cameras {left_socket} and {right_socket} are not linked by toCameraSocket"
        )
    right_from_left = np.linalg.inv(root_from_right[0]) @ root_from_left[0]
    fisheye = left[3] == 1
    rotation, translation = right_from_left[:3, :3], right_from_left[:3, 3]
    return rectify_stereo(
        left[0], left[1], right[0], right[1], rotation, translation, left[2], source,
        extrinsics=f"cameraData[{left_socket}].extrinsics", fisheye=fisheye, units=units,
    )  # fmt: skip


def _camera(
    cameras: dict[int, dict], socket: int, source: str, image_size: tuple[int, int] | None
) -> tuple[np.ndarray, np.ndarray, tuple[int, int], int]:
    """(K, D, size, cameraType) of one camera at the images' size."""
    cam = cameras[socket]
    where = f"cameraData[{socket}]"
    try:
        width, height = int(cam["width"]), int(cam["height"])
        k = numbers(cam["intrinsicMatrix"], 9, source, f"{where}.intrinsicMatrix").reshape(3, 3)
        d = numbers(cam.get("distortionCoeff", []), (0, 4, 5, 8, 12, 14), source, f"{where}.distortionCoeff")
    except KeyError as exc:
        raise CalibrationError(f"{source}: {where}.{exc.args[0]}: required field is missing") from None
    kind = int(cam.get("cameraType", 0))
    if kind == 1:  # fisheye: the equidistant model's four coefficients come first
        d = d[:4] if d.size >= 4 else np.zeros(4)
    if not (k[0, 0] > 0 and k[1, 1] > 0 and width > 0 and height > 0):
        raise CalibrationError(
            f"{source}: {where}: intrinsicMatrix focal lengths and width, height must be > 0"
        )
    size = (width, height) if image_size is None else tuple(image_size)
    scale = size[0] / width
    if abs(size[1] / height - scale) > 1e-6 or scale > 1:
        raise CalibrationError(
            f"{source}: {where}: calibrated at {width}x{height}; the images are {size[0]}x{size[1]}, "
            "not that size scaled down"
        )
    return np.diag([scale, scale, 1.0]) @ k, d, size, kind


def _to_chain_end(cameras: dict[int, dict], socket: int, source: str) -> tuple[np.ndarray, int]:
    """(4x4 transform taking the camera's points to the frame of its chain's last camera, that
    camera's socket), translations as written (centimetres)."""
    transform, seen = np.eye(4), []
    while socket not in seen:
        seen.append(socket)
        extrinsics = (cameras.get(socket) or {}).get("extrinsics") or {}
        target = int(extrinsics.get("toCameraSocket", -1))
        if target < 0 or target not in cameras:
            return transform, socket
        where = f"cameraData[{socket}].extrinsics"
        step = np.eye(4)
        rotation = numbers(extrinsics.get("rotationMatrix"), 9, source, f"{where}.rotationMatrix")
        step[:3, :3] = rotation.reshape(3, 3)
        t = extrinsics.get("translation") or {}
        step[:3, 3] = [float(t.get(axis, 0.0)) for axis in "xyz"]
        rot = step[:3, :3]
        if not (np.allclose(rot @ rot.T, np.eye(3), atol=1e-3) and np.linalg.det(rot) > 0):
            raise CalibrationError(f"{source}: {where}.rotationMatrix: not a rotation matrix")
        transform, socket = step @ transform, target
    loop = " -> ".join(map(str, seen))
    raise CalibrationError(f"{source}: extrinsics: toCameraSocket makes a loop ({loop})")
