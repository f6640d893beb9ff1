"""Bags as real drivers write them, read by ``replay.bag``: encodings, stamps, pose and info topics."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from swarm.formats.errors import InputError
from swarm.streams.frames import to_gray8
from tests.support.driver_bags import CALIB, DriverBag, H, W, _bag, _colour
from tests.support.paths import TEST_DATA

pytest.importorskip("rosbags")


def _gray(k: int) -> np.ndarray:
    return ((np.arange(H * W).reshape(H, W) * 7 + 31 * k) % 256).astype(np.uint8)


def _stereo(bag: DriverBag, times, left="/left", right="/right", pose="/pose") -> None:
    for k, t in enumerate(times):
        bag.image(left, t, _gray(k))
        bag.image(right, t, _gray(k))
        bag.pose(pose, t, [0, 0, 1], [1, 0, 0, 0])


@pytest.mark.parametrize("ros", [1, 2])
def test_a_topic_of_the_wrong_type_is_named_with_the_types_read(tmp_path, ros):
    """--left on a PoseStamped, --pose on an Image, --left-info on an Image: named, never a traceback."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        _stereo(bag, [1.0, 1.05])
        bag.image("/cam0/image_raw", 1.0, _gray(0))
    images = r"sensor_msgs/Image, sensor_msgs/CompressedImage"
    with pytest.raises(RecordingError, match=rf"topic /pose \(left\) is a geometry_msgs/PoseStamped; "
                       rf"the left topic must be one of {images}"):  # fmt: skip
        BagRecording(path, "/pose", "/right", "/cam0/image_raw", CALIB)
    with pytest.raises(RecordingError, match=r"topic /cam0/image_raw \(pose\) is a sensor_msgs/Image; "
                       r"the pose topic must be one of geometry_msgs/PoseStamped"):  # fmt: skip
        BagRecording(path, "/left", "/right", "/cam0/image_raw", CALIB)
    with pytest.raises(RecordingError, match=r"topic /left \(left_info\) is a sensor_msgs/Image; "
                       r"the left_info topic must be one of sensor_msgs/CameraInfo"):  # fmt: skip
        BagRecording(path, "/cam0/image_raw", "/right", "/pose", None, "/left", "/right")
    with pytest.raises(RecordingError, match=r"topic /left is given as both left and right"):
        BagRecording(path, "/left", "/left", "/pose", CALIB)


@pytest.mark.parametrize("ros", [1, 2])
def test_pose_from_tf_odometry_and_transform_stamped_by_child_frame(tmp_path, ros):
    """/tf with several transforms a message, Odometry of the base, a motion-capture TransformStamped:
    the left camera's poses are the messages of its child frame; the frames present are listed."""
    path = _bag(tmp_path, ros)
    times = [1.0, 1.05, 1.1]
    with DriverBag(path, ros) as bag:
        for k, t in enumerate(times):
            bag.image("/left", t, _gray(k))
            bag.image("/right", t, _gray(k))
            bag.tf("/tf", t, [("odom", "base_link", (t, 0, 0)), ("world", "cam0_optical", (t, 5, 1))])
            bag.odometry("/odom", t, "base_link", (t, 1, 0))
            bag.transform_stamped("/vicon/rig/rig", t, "rig", (t, 2, 1))
    rec = BagRecording(path, "/left", "/right", "/tf", CALIB, child_frame="cam0_optical")
    assert np.allclose(rec.positions(), [[t, 5, 1] for t in times])
    rec = BagRecording(path, "/left", "/right", "/vicon/rig/rig", CALIB)
    assert np.allclose(rec.positions(), [[t, 2, 1] for t in times])
    assert [p.t for p in rec.pairs()] == pytest.approx(times)
    rec = BagRecording(path, "/left", "/right", "/odom", CALIB, child_frame="base_link")
    assert np.allclose(rec.positions(), [[t, 1, 0] for t in times])
    with pytest.raises(RecordingError, match=r"topic /odom: no messages with child_frame_id 'cam0_optical' "
                       r"\(child frames: base_link\)"):  # fmt: skip
        BagRecording(path, "/left", "/right", "/odom", CALIB, child_frame="cam0_optical")
    with pytest.raises(RecordingError, match=r"topic /tf: give --child-frame, the left camera's "
                       r"child_frame_id \(child frames: base_link, cam0_optical\)"):  # fmt: skip
        BagRecording(path, "/left", "/right", "/tf", CALIB)


@pytest.mark.parametrize("ros", [1, 2])
def test_stamps_out_of_order_duplicated_or_shared_keep_every_pair(tmp_path, ros):
    """Header stamps out of arrival order (a driver's threads, a merged bag) are sorted; a left stamp
    seen twice is kept once and counted; a right image matched to two left ones serves both (before,
    every later pair was silently lost)."""
    path = _bag(tmp_path, ros)
    left = [(1.0, 0), (1.1, 2), (1.05, 1), (1.05, 1), (1.15, 3), (1.2, 4)]  # (header stamp, image)
    right = [(1.0, 0), (1.05, 1), (1.1, 2), (1.16, 3)]  # the 1.2 right image lost
    with DriverBag(path, ros) as bag:
        for n, (t, k) in enumerate(left):
            bag.raw_image("/left", t, "mono8", _gray(k).tobytes(), log_t=2.0 + n * 0.05)
        for n, (t, k) in enumerate(right):
            bag.raw_image("/right", t, "mono8", _gray(k).tobytes(), log_t=2.0 + n * 0.05)
        for t in (1.0, 1.05, 1.1, 1.15, 1.2):
            bag.pose("/pose", t, [t, 0, 1], [1, 0, 0, 0])
    rec = BagRecording(path, "/left", "/right", "/pose", CALIB, tolerance_s=0.05)
    assert rec.matched.describe() == "5 kept, dropped: 1 duplicate left stamp"
    got = list(rec.pairs())
    assert [p.t for p in got] == pytest.approx([1.0, 1.05, 1.1, 1.15, 1.2])
    for p, k, kr in zip(got, [0, 1, 2, 3, 4], [0, 1, 2, 3, 3], strict=True):
        assert np.array_equal(p.left, _gray(k)) and np.array_equal(p.right, _gray(kr))
        assert p.position[0] == pytest.approx(p.t)
    assert [p.t for p in rec.pairs(3, 2)] == pytest.approx([1.15, 1.2])


@pytest.mark.parametrize("ros", [1, 2])
def test_images_without_stamps_are_named(tmp_path, ros):
    """A driver that leaves header.stamp at 0: refused by name, not one pair at t = 0."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        for n in range(3):
            bag.raw_image("/left", 0.0, "mono8", _gray(n).tobytes(), log_t=1.0 + n)
            bag.raw_image("/right", 0.0, "mono8", _gray(n).tobytes(), log_t=1.0 + n)
            bag.pose("/pose", 0.0, [0, 0, 1], [1, 0, 0, 0])
    with pytest.raises(
        RecordingError, match=r"topic /left: all 3 messages have the header stamp 0.000000000"
    ):
        BagRecording(path, "/left", "/right", "/pose", CALIB)


@pytest.mark.parametrize("ros", [1, 2])
def test_a_camera_info_topic_without_messages_is_named(tmp_path, ros):
    """The info topic recorded but empty (the camera's info published before the recording began)."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        bag.empty_topic("/right/camera_info", "sensor_msgs/msg/CameraInfo")
        bag.camera_info("/left/camera_info", 1.0, (W, H), np.eye(3), [], np.eye(3), np.eye(3, 4))
        _stereo(bag, [1.0, 1.05])
    with pytest.raises(RecordingError, match=r"topic /right/camera_info: no messages"):
        BagRecording(path, "/left", "/right", "/pose", None, "/left/camera_info", "/right/camera_info")


@pytest.mark.parametrize(
    ("name", "content", "error"),
    [
        ("run.bag", b"not a bag", r"run.bag: not a readable ROS 1 or ROS 2 bag \(File magic is invalid"),
        (
            "run.bag.active",
            b"#ROSBAG V2.0\n",
            r"run.bag.active: an unfinished ROS 1 recording .*rosbag reindex",
        ),
        ("ros2/run_0.mcap", b"\x89MCAP0\r\n", r"run_0.mcap: not a readable ROS 1 or ROS 2 bag"),
        ("ros2/run_0.db3.zstd", b"\x28\xb5\x2f\xfd", r"ros2: a ROS 2 bag is a folder with its metadata.yaml"),
    ],
)
def test_a_bag_that_cannot_be_read_is_named(tmp_path, name, content, error):
    """A damaged file, an unfinished ROS 1 recording, a .mcap copied without its metadata.yaml."""
    path = tmp_path / name
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=error):
        BagRecording(path, "/left", "/right", "/pose", CALIB)


def test_a_truncated_ros1_bag_is_named(tmp_path):
    """rosbag record killed: the end of the file (the index) is missing."""
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        _stereo(bag, [1.0, 1.05])
    path.write_bytes(path.read_bytes()[:3000])
    with pytest.raises(RecordingError, match=r"b.bag: not a readable ROS 1 or ROS 2 bag"):
        BagRecording(path, "/left", "/right", "/pose", CALIB)


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
        _stereo(bag, [1.0, 1.05])
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
            image = _gray(k).astype(np.uint16) * np.uint16(scale)
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
        assert np.array_equal(to_gray8(pair.left), _gray(k)) and np.array_equal(
            to_gray8(pair.right), _gray(k)
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


@pytest.mark.parametrize("storage", ["SQLITE3", "MCAP"])
def test_a_file_compressed_ros2_bag_is_read_from_its_zstd_file(tmp_path, storage):
    """ros2 bag record --compression-mode file leaves run_0.db3.zstd (or .mcap.zstd) beside
    metadata.yaml; naming that file, as one names a .db3, said 'Unrecognized storage format'."""
    from rosbags.rosbag2 import writer

    path = tmp_path / "run"
    bag = DriverBag(tmp_path / "unused", 2)
    bag.writer = writer.Writer(path, version=9, storage_plugin=getattr(writer.StoragePlugin, storage))
    bag.writer.set_compression(writer.CompressionMode.FILE, writer.CompressionFormat.ZSTD)
    with bag:
        _stereo(bag, [1.0, 1.05])
    (data,) = path.glob("*.zstd")
    rec = BagRecording(data, "/left", "/right", "/pose", CALIB)
    assert [p.t for p in rec.pairs()] == pytest.approx([1.0, 1.05])


@pytest.mark.parametrize("ros", [1, 2])
def test_nan_or_zero_quaternion_poses_are_skipped_and_counted(tmp_path, ros):
    """A VIO that lost tracking publishes NaN, an unset orientation is w = x = y = z = 0: the NaN was
    sent to the agent as the camera's pose, the zero quaternion stopped the replay with 'a zero
    quaternion is not a rotation', naming no topic. (Poses 0.3 s apart: none is interpolated.)"""
    nan = float("nan")
    path = _bag(tmp_path, ros)
    poses = [([0, 0, 1], [1, 0, 0, 0]), ([nan, nan, nan], [1, 0, 0, 0]), ([0, 0, 1], [0, 0, 0, 0]),
             ([0, 0, 1], [1, 0, 0, 0])]  # fmt: skip
    with DriverBag(path, ros) as bag:
        for k, (t, (xyz, q)) in enumerate(zip([1.0, 1.3, 1.6, 1.9], poses, strict=True)):  # 0.3 s apart
            bag.image("/left", t, _gray(k))
            bag.image("/right", t, _gray(k))
            bag.pose("/pose", t, xyz, q)
            bag.pose("/lost", t, [nan, nan, nan], q)
    rec = BagRecording(path, "/left", "/right", "/pose", CALIB)
    assert rec.matched.describe() == (
        "2 kept, dropped: 2 no pose within 0.01, 2 unusable pose message (NaN, or a zero quaternion)"
    )
    assert [p.t for p in rec.pairs()] == pytest.approx([1.0, 1.9])
    assert np.all(np.isfinite(rec.positions()))
    with pytest.raises(RecordingError, match=r"topic /lost: every message is an unusable pose message"):
        BagRecording(path, "/left", "/right", "/lost", CALIB)


@pytest.mark.parametrize("pattern", ["rggb", "grbg"])
def test_a_png_compressed_bayer_image_is_demosaiced(tmp_path, pattern):
    """image_transport's compressed PNG of a Bayer camera holds the raw mosaic, with the format
    'bayer_rggb8; png compressed ': it was read as a gray image, the mosaic's checkerboard in it."""
    bgr = _colour()
    gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(int)
    data = np.frombuffer(cv2.imencode(".png", _mosaic(bgr, pattern))[1].tobytes(), np.uint8)
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        msg = bag.t["sensor_msgs/msg/CompressedImage"](
            header=bag.header(1.0), format=f"bayer_{pattern}8; png compressed ", data=data
        )
        for topic in ("/left", "/right"):
            bag.write(topic, "sensor_msgs/msg/CompressedImage", msg, 1.0)
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    (pair,) = BagRecording(path, "/left", "/right", "/pose", CALIB).pairs()
    error = np.abs(to_gray8(pair.left).astype(int) - gray)[2:-2, 2:-2]
    assert error.mean() < 1.0 and error.max() <= 3, (error.mean(), error.max())


@pytest.mark.slow
@pytest.mark.parametrize("ros", [1, 2])
def test_camera_info_of_a_binned_camera_is_scaled_and_a_roi_is_named(tmp_path, ros):
    """A driver binning 2x2 publishes half-size images with the CameraInfo of the full sensor and
    binning_x = binning_y = 2 (REP-104): it was refused as 'images are 376x240, the calibration is
    for 752x480'. K and P are now scaled by the binning; a region of interest is refused by name."""
    from swarm.streams.frames import make_frame, rectified_camera
    from tests.support.euroc_bags import _euroc_camera_infos

    size, left, right = _euroc_camera_infos()
    half = (size[0] // 2, size[1] // 2)
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        bag.camera_info_binned("/left/camera_info", 1.0, size, *left, binning=2)
        bag.camera_info_binned("/right/camera_info", 1.0, size, *right, binning=2)
        bag.camera_info_binned("/roi/camera_info", 1.0, size, *right, roi=(8, 0, 640, 480))
        for t in (1.0, 1.05):
            for topic in ("/left", "/right"):
                bag.raw_image(topic, t, "mono8", np.zeros(half[::-1], np.uint8).tobytes(), *half)
            bag.pose("/pose", t, [0, 0, 1], [1, 0, 0, 0])
    rec = BagRecording(path, "/left", "/right", "/pose", None, "/left/camera_info", "/right/camera_info")
    calib = rec.calibration
    assert calib.image_size == half
    assert calib.fx == pytest.approx(left[3][0, 0] / 2) and calib.cy == pytest.approx(left[3][1, 2] / 2)
    assert calib.baseline == pytest.approx(-right[3][0, 3] / right[3][0, 0])
    (pair, _) = rec.pairs()
    frame = make_frame("r1", 0, pair, calib, rectified_camera(calib))
    assert frame.left.shape == half[::-1]
    with pytest.raises(InputError, match=r"/roi/camera_info: roi: images of a region of interest "
                       r"\(640x480 at 8, 0 of 752x480\) are not supported"):  # fmt: skip
        BagRecording(path, "/left", "/right", "/pose", None, "/left/camera_info", "/roi/camera_info")


@pytest.mark.slow
@pytest.mark.parametrize("ros", [1, 2])
def test_poses_slower_than_the_camera_are_interpolated(tmp_path, ros):
    """10 Hz odometry (or /tf) with a 20 Hz camera: every other image had no pose within 10 ms
    and was dropped. Between two poses at most 0.2 s apart, the pose is now interpolated; images
    before the first pose, after the last, or across a gap stay dropped."""
    from swarm.streams.poses import quaternion_matrix

    path = _bag(tmp_path, ros)
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    with DriverBag(path, ros) as bag:
        for k, t in enumerate([0.95, 1.0, 1.05, 1.1, 1.15, 1.5, 1.55]):
            bag.image("/left", t, _gray(k))
            bag.image("/right", t, _gray(k))
        bag.pose("/odom", 1.0, [0, 0, 1], [1, 0, 0, 0])
        bag.pose("/odom", 1.1, [2, 0, 1], [c, 0, 0, s])  # turned 90 degrees about z
        bag.pose("/odom", 1.5, [2, 0, 1], [c, 0, 0, s])
    rec = BagRecording(path, "/left", "/right", "/odom", CALIB)
    assert rec.matched.describe() == "4 kept, dropped: 3 no pose within 0.01"
    assert rec.interpolated_poses == 1
    pairs = list(rec.pairs())
    assert [p.t for p in pairs] == pytest.approx([1.0, 1.05, 1.1, 1.5])
    assert np.allclose(pairs[1].position, [1, 0, 1])
    half = quaternion_matrix(np.cos(np.pi / 8), 0, 0, np.sin(np.pi / 8))  # 45 degrees about z
    assert np.allclose(pairs[1].world_R_optical, half)


@pytest.mark.parametrize("ros", [1, 2])
def test_topics_stamped_by_different_clocks_show_their_time_spans(tmp_path, ros):
    """A motion-capture PC stamping poses with its own clock (or sim time against wall time):
    nothing matches, and the error shows each topic's stamps so that the offset is seen."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        for k, t in enumerate([1000.0, 1000.05]):
            bag.image("/left", t, _gray(k))
            bag.image("/right", t, _gray(k))
            bag.pose("/mocap", t - 990.0, [0, 0, 1], [1, 0, 0, 0])
    spans = r"/left 1000.000 .. 1000.050, /right 1000.000 .. 1000.050, /mocap 10.000 .. 10.050"
    error = rf"\(0 kept, dropped: 2 no pose within 0.01\); header stamps \(s\): {spans}: are the topics"
    with pytest.raises(RecordingError, match=rf"no pair left after matching {error} stamped by one clock\?"):
        BagRecording(path, "/left", "/right", "/mocap", CALIB)


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
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        msg = bag.t["sensor_msgs/msg/CompressedImage"](header=bag.header(1.0), format=fmt, data=data)
        for topic in ("/left", "/right"):
            bag.write(topic, "sensor_msgs/msg/CompressedImage", msg, 1.0)
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    with pytest.raises(RecordingError) as info:
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert str(info.value).startswith("/left: ") and words in str(info.value), str(info.value)


def _as_recorded_by_humble(folder: Path) -> None:
    """Rewrite a ROS 2 bag as rosbag2 before Iron writes it: metadata version 5, no type hashes,
    and no message definitions in the .db3 (schema 3: no message_definitions table)."""
    import sqlite3

    import yaml

    meta_path = folder / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    info["version"] = 5
    for topic in info["topics_with_message_count"]:
        topic["topic_metadata"].pop("type_description_hash", None)
    meta_path.write_text(yaml.safe_dump(meta))
    for db in folder.glob("*.db3"):
        con = sqlite3.connect(db)
        con.executescript(
            "DROP TABLE message_definitions;"
            "CREATE TABLE t2(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
            " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
            "INSERT INTO t2 SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics;"
            "DROP TABLE topics; ALTER TABLE t2 RENAME TO topics; UPDATE schema SET schema_version = 3;"
        )
        con.close()


@pytest.mark.slow
def test_a_ros2_bag_without_message_definitions_is_read(tmp_path):
    """Bags of Foxy and Humble carry no message definitions: rosbags refused them with 'Bag
    contains no type definitions' (mbpeterson70/robotdatapy#30); the standard types are known."""
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        _stereo(bag, [1.0, 1.05])
    want = [
        (p.left.copy(), p.right.copy()) for p in BagRecording(path, "/left", "/right", "/pose", CALIB).pairs()
    ]
    _as_recorded_by_humble(path)
    got = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(got) == len(want) == 2
    for pair, (left, right) in zip(got, want, strict=True):
        assert np.array_equal(pair.left, left) and np.array_equal(pair.right, right)


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize("role", ["left", "pose"])
def test_a_message_that_does_not_deserialize_is_named_with_its_topic(tmp_path, ros, role):
    """A message cut short (a recorder killed mid-write, a type whose definition changed) raised
    rosbags' AnyReaderError as a traceback."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        _stereo(bag, [1.0, 1.05])
        bag.writer.write(bag.conns[f"/{role}"], int(1.1e9), b"\x01\x02\x03")
    with pytest.raises(
        RecordingError, match=rf"^/{role}: the message logged at 1.100000000 s is not a valid "
    ):
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())


@pytest.mark.parametrize(("compression", "magic"), [("BZ2", b"BZh"), ("LZ4", b"\x04\x22\x4d\x18")])
def test_a_damaged_compressed_chunk_is_named(tmp_path, compression, magic):
    """A ROS 1 bag of bz2 / lz4 chunks reads as the uncompressed one; a chunk damaged after the
    start raised bz2's OSError or lz4's RuntimeError as a traceback (rosbags passes them on)."""
    from rosbags.rosbag1 import Writer

    path = _bag(tmp_path, 1)
    bag = DriverBag(path, 1)
    bag.writer.set_compression(getattr(Writer.CompressionFormat, compression))
    bag.writer.chunk_threshold = 200  # several chunks
    with bag:
        _stereo(bag, [1.0 + 0.05 * k for k in range(6)])
    pairs = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(pairs) == 6 and np.array_equal(pairs[5].left, _gray(5))
    raw = bytearray(path.read_bytes())
    at = raw.find(magic, len(raw) // 2)
    raw[at + 8 : at + 60] = b"\xff" * 52
    path.write_bytes(bytes(raw))
    with pytest.raises(RecordingError, match=r"b.bag: the bag is damaged after its start \("):
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())


@pytest.mark.parametrize(
    ("metadata", "words"),
    [
        ("rosbag2_bagfile_information: [\n", "Could not load YAML"),  # PyYAML's error spans lines
        ("foo: 1\n", "rosbag2_bagfile_information"),
    ],
)
def test_a_damaged_metadata_yaml_is_named_on_one_line(tmp_path, metadata, words):
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        _stereo(bag, [1.0])
    (path / "metadata.yaml").write_text(metadata)
    with pytest.raises(RecordingError, match="not a readable ROS 1 or ROS 2 bag") as info:
        BagRecording(path, "/left", "/right", "/pose", CALIB)
    assert words in str(info.value) and "\n" not in str(info.value), str(info.value)


def test_a_custom_topic_with_an_empty_definition_does_not_refuse_the_bag(tmp_path):
    """rosbag2 leaves the definition of a type it cannot find empty (ros2/rosbag2#1922, #1350)
    but stores its hash: rosbags refused the whole bag on that hash, though the stereo topics are
    standard ones with good definitions."""
    import sqlite3

    from rosbags.typesys import get_types_from_msg

    path = _bag(tmp_path, 2)
    bag = DriverBag(path, 2)
    bag.store.register(
        get_types_from_msg("float64 exposure\nint32 gain\n", "realsense2_camera_msgs/msg/Metadata")
    )
    with bag:
        _stereo(bag, [1.0, 1.05])
        meta = bag.store.types["realsense2_camera_msgs/msg/Metadata"](exposure=1.0, gain=2)
        bag.write("/meta", "realsense2_camera_msgs/msg/Metadata", meta, 1.0)
    con = sqlite3.connect(next(path.glob("*.db3")))
    con.execute(
        "UPDATE message_definitions SET encoded_message_definition = '' WHERE topic_type LIKE 'realsense%'"
    )
    con.commit()
    con.close()
    pairs = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(pairs) == 2 and np.array_equal(pairs[1].left, _gray(1))
    with pytest.raises(RecordingError, match=r"topic /meta \(pose\) is not in the bag"):
        BagRecording(path, "/left", "/right", "/meta", CALIB)


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_ros2_bag_file_copied_without_its_metadata_is_read(tmp_path, storage):
    """A .mcap or .db3 copied alone (its metadata.yaml left behind) was refused with 'ros2 bag
    reindex'; rosbags reads either file by itself."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = _bag(tmp_path, 2)
    bag = DriverBag(path, 2)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    bag.writer = Writer(path, version=9, storage_plugin=plugin)
    with bag:
        _stereo(bag, [1.0, 1.05])
    (single,) = [f for f in path.iterdir() if f.suffix in (".db3", ".mcap")]
    alone = tmp_path / "copied" / single.name
    alone.parent.mkdir()
    alone.write_bytes(single.read_bytes())
    want = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    got = list(BagRecording(alone, "/left", "/right", "/pose", CALIB).pairs())
    assert len(got) == len(want) == 2
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)


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
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        msg = bag.t["sensor_msgs/msg/CompressedImage"](header=bag.header(1.0), format=fmt, data=data)
        for topic in ("/left", "/right"):
            bag.write(topic, "sensor_msgs/msg/CompressedImage", msg, 1.0)
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    (pair,) = BagRecording(path, "/left", "/right", "/pose", CALIB).pairs()
    error = np.abs(to_gray8(pair.left).astype(int) - want)
    assert error.max() <= (6 if ext == ".jpg" else 0), error.max()
