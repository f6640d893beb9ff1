"""ROS camera messages: ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` to pixels,
``sensor_msgs/CameraInfo`` to a camera's calibration.

Raw images are read by their ``encoding`` (``sensor_msgs/image_encodings``: mono, BGR/RGB with
or without alpha, 16-bit, YUV 4:2:2, YUV 4:2:0 NV12/NV21 and Bayer mosaics), with row padding
(``step``) and big-endian 16-bit data; YUV gives its luma, Bayer mosaics are demosaiced to gray. Compressed
images are decoded by OpenCV; image_transport's format string (``"ENCODING; png compressed"``)
tells a compressed Bayer mosaic, demosaiced here too.

16-bit images hold a 10- or 12-bit camera's values in their low bits (0..1023, 0..4095), whose top
8 bits would be black: ``swarm.formats.pixel_bits`` finds the bits and scales by them.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from swarm.formats.calibration_formats import CameraInfo
from swarm.formats.errors import RecordingError

# sensor_msgs/image_encodings read (lower case): (pixel type, values a pixel, conversion to gray or BGR)
_ENCODINGS: dict[str, tuple[type, int, Any]] = {
    "mono8": (np.uint8, 1, None),
    "8uc1": (np.uint8, 1, None),
    "mono16": (np.uint16, 1, None),
    "16uc1": (np.uint16, 1, None),
    "bgr8": (np.uint8, 3, None),
    "8uc3": (np.uint8, 3, None),  # cv_bridge's BGR
    "rgb8": (np.uint8, 3, cv2.COLOR_RGB2BGR),
    "bgra8": (np.uint8, 4, None),
    "8uc4": (np.uint8, 4, None),
    "rgba8": (np.uint8, 4, cv2.COLOR_RGBA2BGRA),
    "bgr16": (np.uint16, 3, None),
    "rgb16": (np.uint16, 3, cv2.COLOR_RGB2BGR),
    # YUV 4:2:2, two bytes a pixel: the gray image is the luma Y, at byte 1 (UYVY) or 0 (YUYV)
    "yuv422": (np.uint8, 2, ("luma", 1)),  # UYVY, usb_cam's and image_encodings' "yuv422"
    "uyvy": (np.uint8, 2, ("luma", 1)),
    "yuv422_yuy2": (np.uint8, 2, ("luma", 0)),  # YUYV
    "yuyv": (np.uint8, 2, ("luma", 0)),
    # YUV 4:2:0 semi-planar (ROS 2's nv12/nv21: Raspberry Pi camera_ros, OAK cameras): the rows of
    # the luma plane (one byte a pixel, ``step`` apart) then half as many of chroma; gray is the luma
    "nv12": (np.uint8, 1, None),
    "nv21": (np.uint8, 1, None),
    "rgba16": (np.uint16, 4, cv2.COLOR_RGBA2BGRA),
    "bgra16": (np.uint16, 4, None),
}
#: rows of data per image row (image_encodings' getHeightScaling): the chroma plane's follow
_HEIGHT_SCALING = {"nv12": 1.5, "nv21": 1.5}
# Bayer mosaics, demosaiced to gray; OpenCV names a pattern by its second row's middle pixels
_BAYER = {"rggb": cv2.COLOR_BayerBG2GRAY, "bggr": cv2.COLOR_BayerRG2GRAY,
          "gbrg": cv2.COLOR_BayerGR2GRAY, "grbg": cv2.COLOR_BayerGB2GRAY}  # fmt: skip
for _pattern, _code in _BAYER.items():
    _ENCODINGS[f"bayer_{_pattern}8"] = (np.uint8, 1, _code)
    _ENCODINGS[f"bayer_{_pattern}16"] = (np.uint16, 1, _code)
ENCODINGS = tuple(_ENCODINGS)


def decode_image(msg: Any, where: str) -> np.ndarray:
    """A uint8/uint16 image from a sensor_msgs Image or CompressedImage message."""
    if hasattr(msg, "format"):  # CompressedImage
        data = np.asarray(msg.data, dtype=np.uint8)
        if "compresseddepth" in str(msg.format).lower():
            raise RecordingError(
                f"{where}: format {msg.format!r}: a compressedDepth image is a depth map; "
                "--left and --right take the cameras' images"
            )
        if data.size == 0:  # a recorder that dropped the payload (rosjava/android_core#29)
            raise RecordingError(f"{where}: compressed image ({msg.format!r}) holds no data (0 bytes)")
        try:
            image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        except cv2.error:
            image = None
        if image is None:
            raise RecordingError(f"{where}: compressed image ({msg.format!r}) does not decode")
        # image_transport's format is "ENCODING; png compressed [TARGET]": a Bayer image is
        # compressed as its raw mosaic (no target), to be demosaiced here
        original, _, compressed = str(msg.format).lower().partition(";")
        original = original.strip()
        if original.startswith("bayer_") and original in _ENCODINGS and image.ndim == 2:
            image = cv2.cvtColor(image, _ENCODINGS[original][2])
        # a TARGET of rgb8/rgba8 was handed to the encoder in that order, which OpenCV takes for
        # BGR: decoded, its channels come back red first (image_transport turns them round too)
        target = compressed.split("compressed", 1)[1].strip() if "compressed" in compressed else ""
        if target.startswith("rgb") and image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR if image.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
        return image
    encoding = str(msg.encoding).lower()
    if encoding not in _ENCODINGS:
        raise RecordingError(
            f"{where}: image encoding {msg.encoding!r} is not supported (supported: {', '.join(ENCODINGS)})"
        )
    dtype, channels, convert = _ENCODINGS[encoding]
    row_bytes = msg.width * channels * np.dtype(dtype).itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    scaling = _HEIGHT_SCALING.get(encoding, 1.0)
    if msg.width < 1 or msg.height < 1 or msg.step < row_bytes or data.size < msg.step * msg.height * scaling:
        rows = "height" if scaling == 1.0 else f"{scaling:g} x height (the luma, then the chroma)"
        raise RecordingError(
            f"{where}: a {msg.width}x{msg.height} {msg.encoding} image needs step >= {row_bytes} and "
            f"{rows} * step bytes of data; it has step {msg.step} and {data.size} bytes"
        )
    row = data[: msg.step * msg.height].reshape(msg.height, msg.step)
    pixels = row[:, :row_bytes].copy().view(dtype)
    if np.dtype(dtype).itemsize > 1 and bool(msg.is_bigendian):
        pixels = pixels.byteswap()
    image = (
        pixels.reshape(msg.height, msg.width, channels)
        if channels > 1
        else pixels.reshape(msg.height, msg.width)
    )
    if isinstance(convert, tuple):  # ("luma", byte of Y)
        return np.ascontiguousarray(image[:, :, convert[1]])
    if convert is not None:
        image = cv2.cvtColor(image, convert)
    return image


def camera_info(msg: Any, where: str) -> CameraInfo:
    """The CameraInfo of the images as published (binning and region of interest as
    ``CameraInfo.from_dict`` reads them, the same as in a camera_info file)."""
    data: dict[str, Any] = {"width": int(msg.width), "height": int(msg.height)}
    data["distortion_model"] = msg.distortion_model
    for name in ("k", "d", "r", "p"):  # ROS 2 names; ROS 1 spells them K D R P
        data[name] = list(getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper()))
    data["binning_x"], data["binning_y"] = int(msg.binning_x), int(msg.binning_y)
    roi = msg.roi
    data["roi"] = {"x_offset": int(roi.x_offset), "y_offset": int(roi.y_offset)}
    data["roi"].update(width=int(roi.width), height=int(roi.height))
    return CameraInfo.from_dict(data, where)


def split_side_by_side(image: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The (left, right) halves of a side-by-side stereo image (a double-width image, the left
    camera's in its left half, as ZED and USB stereo cameras send it). An odd width raises
    RecordingError naming ``where``."""
    height, width = image.shape[:2]
    if width % 2:
        raise RecordingError(
            f"{where}: a side-by-side pair is a double-width image; {width}x{height} has an odd width"
        )
    half = width // 2
    return np.ascontiguousarray(image[:, :half]), np.ascontiguousarray(image[:, half:])
