"""ROS 2's YUV 4:2:0 encodings (``nv12``, ``nv21``: ros2/common_interfaces#253, #264) and the
16-bit colour ones with alpha (``rgba16``, ``bgra16``), as cameras publish them
(christianrauch/camera_ros#54: a Raspberry Pi camera's ``nv21``; luxonis/depthai-ros#20: an OAK
camera's ``nv12``). Before, each was refused as an unsupported encoding."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from swarm.streams.frames import to_gray8
from tests.support.driver_bags import CALIB, DriverBag, H, W, _bag, _colour

pytest.importorskip("rosbags")


def _nv(bgr: np.ndarray, encoding: str, pad: int) -> tuple[bytes, int]:
    """The NV12 / NV21 bytes of ``bgr`` (OpenCV's I420 reordered: Y rows, then interleaved
    chroma at half resolution), each row padded by ``pad`` bytes; and the step."""
    i420 = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420)
    y, u, v = (
        i420[:H],
        i420[H : H + H // 4].reshape(H // 2, W // 2),
        i420[H + H // 4 :].reshape(H // 2, W // 2),
    )
    chroma = np.empty((H // 2, W), np.uint8)
    first, second = (u, v) if encoding == "nv12" else (v, u)
    chroma[:, 0::2], chroma[:, 1::2] = first, second
    planes = np.vstack([y, chroma])
    padded = np.zeros((planes.shape[0], W + pad), np.uint8)
    padded[:, :W] = planes
    return padded.tobytes(), W + pad


@pytest.mark.slow
@pytest.mark.parametrize(
    ("encoding", "pad"), [("nv12", 0), ("nv21", 0), ("nv12", 16), ("rgba16", 0), ("bgra16", 0)]
)
def test_yuv420_and_16_bit_alpha_images_give_their_gray(tmp_path, encoding, pad):
    bgr = _colour()
    if encoding.startswith("nv"):
        data, step = _nv(bgr, encoding, pad)
        want = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420)[:H].astype(int)  # the luma
    else:
        bgra = cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA).astype(np.uint16) * 257
        pixels = bgra if encoding == "bgra16" else cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGBA)
        data, step = pixels.tobytes(), W * 8
        want = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        for t in (1.0, 1.05):
            for topic in ("/left", "/right"):
                bag.raw_image(topic, t, encoding, data, step=step)
            bag.pose("/pose", t, [0, 0, 1], [1, 0, 0, 0])
    pairs = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(pairs) == 2
    assert np.abs(to_gray8(pairs[0].left).astype(int) - want).max() <= 1


def test_an_nv12_image_without_its_chroma_rows_is_refused_naming_them(tmp_path):
    data, step = _nv(_colour(), "nv12", 0)
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        for topic in ("/left", "/right"):
            bag.raw_image(topic, 1.0, "nv12", data[: W * H], step=step)  # the luma plane only
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    with pytest.raises(RecordingError, match=r"/left: a 16x12 nv12 image needs step >= 16 and 1.5 x height"):
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
