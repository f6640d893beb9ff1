"""Images as real drivers encode them, read by ``replay.bag``: YUV, Bayer (raw and PNG
compressed), 16-bit, colour, other sizes, and the encodings and images that are refused by name."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from swarm.streams.frames import to_gray8
from tests.support.driver_bags import CALIB, DriverBag, H, W, _bag, _colour, gray_pattern, record_stereo
from tests.support.paths import TEST_DATA

pytest.importorskip("rosbags")


def _compressed_pair_bag(tmp_path, fmt: str, data: np.ndarray):
    """A one-pair bag whose left and right images are the same CompressedImage (``fmt``, ``data``)."""
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        msg = bag.t["sensor_msgs/msg/CompressedImage"](header=bag.header(1.0), format=fmt, data=data)
        for topic in ("/left", "/right"):
            bag.write(topic, "sensor_msgs/msg/CompressedImage", msg, 1.0)
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    return path


def _mosaic(bgr: np.ndarray, pattern: str) -> np.ndarray:
    """The Bayer mosaic a sensor with ``pattern`` (first two rows, e.g. rggb) records of ``bgr``."""
    out = np.zeros(bgr.shape[:2], bgr.dtype)
    for n, colour in enumerate(pattern):
        out[n // 2 :: 2, n % 2 :: 2] = bgr[n // 2 :: 2, n % 2 :: 2, "bgr".index(colour)]
    return out


def _yuv422(bgr: np.ndarray, uyvy: bool) -> np.ndarray:
    yuv = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV)
    packed = np.zeros((H, W * 2), np.uint8)
    y, u, v = yuv[..., 0], yuv[:, ::2, 1], yuv[:, ::2, 2]
    if uyvy:
        packed[:, 1::2], packed[:, 0::4], packed[:, 2::4] = y, u, v
    else:
        packed[:, 0::2], packed[:, 1::4], packed[:, 3::4] = y, u, v
    return packed


@pytest.mark.slow
@pytest.mark.parametrize(
    "encoding",
    ["yuv422", "uyvy", "yuv422_yuy2", "yuyv", "bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8",
     "bayer_rggb16", "8UC3", "rgb8"],
)  # fmt: skip
def test_yuv_and_bayer_images_give_their_gray(tmp_path, encoding):
    """usb_cam's YUV 4:2:2 (UYVY or YUYV) gives its luma; an industrial camera's Bayer mosaic is
    demosaiced with its own pattern (OpenCV names patterns one row lower: RGGB is its BayerBG)."""
    bgr = _colour()
    gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    if encoding.startswith("bayer"):
        data = _mosaic(bgr, encoding[6:10])
        if encoding.endswith("16"):
            data = data.astype(np.uint16) * 257
    elif encoding in ("yuv422", "uyvy", "yuv422_yuy2", "yuyv"):
        data = _yuv422(bgr, uyvy=encoding in ("yuv422", "uyvy"))
    else:
        data = bgr[..., ::-1] if encoding == "rgb8" else bgr
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        for t in (1.0, 1.05):
            for topic in ("/left", "/right"):
                bag.raw_image(topic, t, encoding, np.ascontiguousarray(data).tobytes())
            bag.pose("/pose", t, [0, 0, 1], [1, 0, 0, 0])
    pairs = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(pairs) == 2
    got = to_gray8(pairs[0].left).astype(int)
    error = np.abs(got - gray)[2:-2, 2:-2]  # a demosaic's borders are approximate
    assert error.mean() < 1.0 and error.max() <= 3, (encoding, error.mean(), error.max())


def test_an_unsupported_encoding_lists_the_supported_ones(tmp_path):
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        for topic in ("/left", "/right"):
            bag.raw_image(topic, 1.0, "32FC1", np.zeros(H * W * 4, np.uint8).tobytes())
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    with pytest.raises(RecordingError, match=r"/left: image encoding '32FC1' is not supported "
                       r"\(supported: mono8, 8uc1, mono16, .*yuv422, .*bayer_rggb8"):  # fmt: skip
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())


def test_images_of_another_size_or_short_data_are_named_when_the_bag_is_opened(tmp_path):
    """Before, a calibration for other images, or an Image whose data is shorter than height * step,
    failed with a ValueError traceback once the map server and agent were running."""
    from swarm.formats.calibration_formats import load_stereo_calibration
    from swarm.formats.stereo_calibration import CalibrationError

    euroc = TEST_DATA / "euroc_mini" / "mav0"
    calib = load_stereo_calibration(euroc / "cam0/sensor.yaml", euroc / "cam1/sensor.yaml")
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        record_stereo(bag, [1.0, 1.05])
        bag.raw_image("/short", 1.0, "mono16", np.zeros(H * W * 2 - 5, np.uint8).tobytes(), step=2 * W)
    with pytest.raises(
        CalibrationError, match=r"b.bag: topic /left: images are 16x12, the calibration .* is for 752x480"
    ):
        BagRecording(path, "/left", "/right", "/pose", calib)
    with pytest.raises(RecordingError, match=r"/short: a 16x12 mono16 image needs step >= 32 and "
                       r"height \* step bytes of data; it has step 32 and 379 bytes"):  # fmt: skip
        BagRecording(path, "/short", "/right", "/pose", CALIB)


@pytest.mark.slow
@pytest.mark.parametrize(("scale", "bits"), [(16, 12), (4, 10), (257, 16)])
@pytest.mark.parametrize("compressed", [False, True])
def test_16_bit_images_are_scaled_by_their_significant_bits(tmp_path, scale, bits, compressed):
    """A 12-bit (or 10-bit) camera's mono16 holds 0..4095: its top 8 bits were a black image. The
    brightest pixel of sampled images sets the bits; full-range 16-bit keeps its top 8 bits."""
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        for k, t in enumerate((1.0, 1.05)):
            image = gray_pattern(k).astype(np.uint16) * np.uint16(scale)
            for topic in ("/left", "/right"):
                if compressed:
                    data = np.frombuffer(cv2.imencode(".png", image)[1].tobytes(), np.uint8)
                    msg = bag.t["sensor_msgs/msg/CompressedImage"](
                        header=bag.header(t), format="mono16; png compressed mono16", data=data
                    )
                    bag.write(topic, "sensor_msgs/msg/CompressedImage", msg, t)
                else:
                    bag.raw_image(topic, t, "mono16", image.tobytes())
            bag.pose("/pose", t, [0, 0, 1], [1, 0, 0, 0])
    rec = BagRecording(path, "/left", "/right", "/pose", CALIB)
    assert rec.pixel_bits == bits
    pairs = list(rec.pairs())
    assert len(pairs) == 2
    for k, pair in enumerate(pairs):
        assert np.array_equal(to_gray8(pair.left), gray_pattern(k)) and np.array_equal(
            to_gray8(pair.right), gray_pattern(k)
        )


@pytest.mark.slow
@pytest.mark.parametrize("ros", [1, 2])
def test_16_bit_images_of_a_camera_that_starts_in_the_dark_keep_their_bits(tmp_path, ros):
    """A 12-bit camera whose first 40 of 100 images are dark (values under 200): the bits came
    from the first 30 images, 8 of them, and every later image saturated to white. They now come
    from images spread over the whole recording: 12 bits, and the bright images keep their grey."""
    path = _bag(tmp_path, ros)
    ramp = np.arange(H * W, dtype=np.uint16).reshape(H, W)
    frames = []
    with DriverBag(path, ros) as bag:
        for k in range(100):
            t = 1.0 + 0.05 * k
            image = ramp + np.uint16(k) if k < 40 else ramp * np.uint16(20) + np.uint16(k)  # up to 3919
            frames.append(image)
            for topic in ("/left", "/right"):
                bag.raw_image(topic, t, "mono16", image.tobytes())
            bag.pose("/pose", t, [0, 0, 1], [1, 0, 0, 0])
    rec = BagRecording(path, "/left", "/right", "/pose", CALIB)
    assert rec.pixel_bits == 12
    pairs = list(rec.pairs())
    assert len(pairs) == 100
    for k in (0, 39, 40, 99):
        want = (frames[k] >> 4).astype(np.uint8)
        assert np.array_equal(pairs[k].left, want) and np.array_equal(pairs[k].right, want), k
    assert pairs[99].left.max() == 3919 >> 4  # not saturated at 255
    from swarm.formats.pixel_bits import SignificantBits

    picked = SignificantBits({"/a": 100, "/b": 0}, samples=5)  # /b: no count in the bag's index
    assert [k for k in range(100) if picked.wants("/a", k)] == [0, 25, 50, 74, 99]
    assert [k for k in range(100) if picked.wants("/b", k)] == [0, 1, 2, 3, 4]  # its first ones


@pytest.mark.parametrize("pattern", ["rggb", "grbg"])
def test_a_png_compressed_bayer_image_is_demosaiced(tmp_path, pattern):
    """image_transport's compressed PNG of a Bayer camera holds the raw mosaic, with the format
    'bayer_rggb8; png compressed ': it was read as a gray image, the mosaic's checkerboard in it."""
    bgr = _colour()
    gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    data = np.frombuffer(cv2.imencode(".png", _mosaic(bgr, pattern))[1].tobytes(), np.uint8)
    path = _compressed_pair_bag(tmp_path, f"bayer_{pattern}8; png compressed ", data)
    (pair,) = BagRecording(path, "/left", "/right", "/pose", CALIB).pairs()
    error = np.abs(to_gray8(pair.left).astype(int) - gray)[2:-2, 2:-2]
    assert error.mean() < 1.0 and error.max() <= 3, (error.mean(), error.max())


@pytest.mark.parametrize(
    ("fmt", "data", "words"),
    [
        ("jpeg", np.zeros(0, np.uint8), "holds no data (0 bytes)"),  # rosjava/android_core#29
        ("rgb8; jpeg compressed bgr8", np.frombuffer(b"\xff\xd8 not a jpeg", np.uint8), "does not decode"),
        ("16UC1; compressedDepth png", np.zeros(40, np.uint8), "a compressedDepth image is a depth map"),
    ],
)
def test_compressed_images_that_do_not_decode_are_named(tmp_path, fmt, data, words):
    """An empty CompressedImage raised OpenCV's '!buf.empty()' assertion as a traceback."""
    path = _compressed_pair_bag(tmp_path, fmt, data)
    with pytest.raises(RecordingError) as info:
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert str(info.value).startswith("/left: ") and words in str(info.value), str(info.value)


@pytest.mark.parametrize(
    ("fmt", "order"),
    [("rgb8; jpeg compressed bgr8", "bgr"), ("rgb8; png compressed rgb8", "rgb"),
     ("rgba8; png compressed rgba8", "rgba"), ("png", "bgr")],
)  # fmt: skip
def test_compressed_colour_gives_the_gray_of_its_colours(tmp_path, fmt, order):
    """image_transport hands the encoder the TARGET's channel order (jsk-ros-pkg/coral_usb_ros#104,
    microsoft/Azure_Kinect_ROS_Driver#146): a '... compressed rgb8' image decodes red first; its
    gray was taken with the blue and red weights swapped."""
    bgr = _colour()
    want = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    stored = {
        "bgr": bgr,
        "rgb": bgr[..., ::-1],
        "rgba": np.dstack([bgr[..., ::-1], np.full(bgr.shape[:2], 255)]),
    }
    ext = ".jpg" if "jpeg" in fmt else ".png"
    data = np.frombuffer(cv2.imencode(ext, stored[order].astype(np.uint8))[1].tobytes(), np.uint8)
    path = _compressed_pair_bag(tmp_path, fmt, data)
    (pair,) = BagRecording(path, "/left", "/right", "/pose", CALIB).pairs()
    error = np.abs(to_gray8(pair.left).astype(int) - want)
    assert error.max() <= (6 if ext == ".jpg" else 0), error.max()
