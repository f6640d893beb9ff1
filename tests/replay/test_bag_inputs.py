"""Bags as real drivers write them, read by ``replay.bag``: stamps, poses (tf, Odometry,
TransformStamped), camera_info topics and the topics' types."""

from __future__ import annotations

import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from swarm.formats.errors import InputError
from tests.support.driver_bags import CALIB, DriverBag, H, W, _bag, gray_pattern, record_stereo

pytest.importorskip("rosbags")


@pytest.mark.parametrize("ros", [1, 2])
def test_a_topic_of_the_wrong_type_is_named_with_the_types_read(tmp_path, ros):
    """--left on a PoseStamped, --pose on an Image, --left-info on an Image: named, never a traceback."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        record_stereo(bag, [1.0, 1.05])
        bag.image("/cam0/image_raw", 1.0, gray_pattern(0))
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
            bag.image("/left", t, gray_pattern(k))
            bag.image("/right", t, gray_pattern(k))
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
            bag.raw_image("/left", t, "mono8", gray_pattern(k).tobytes(), log_t=2.0 + n * 0.05)
        for n, (t, k) in enumerate(right):
            bag.raw_image("/right", t, "mono8", gray_pattern(k).tobytes(), log_t=2.0 + n * 0.05)
        for t in (1.0, 1.05, 1.1, 1.15, 1.2):
            bag.pose("/pose", t, [t, 0, 1], [1, 0, 0, 0])
    rec = BagRecording(path, "/left", "/right", "/pose", CALIB, tolerance_s=0.05)
    assert rec.matched.describe() == "5 kept, dropped: 1 duplicate left stamp"
    got = list(rec.pairs())
    assert [p.t for p in got] == pytest.approx([1.0, 1.05, 1.1, 1.15, 1.2])
    for p, k, kr in zip(got, [0, 1, 2, 3, 4], [0, 1, 2, 3, 3], strict=True):
        assert np.array_equal(p.left, gray_pattern(k)) and np.array_equal(p.right, gray_pattern(kr))
        assert p.position[0] == pytest.approx(p.t)
    assert [p.t for p in rec.pairs(3, 2)] == pytest.approx([1.15, 1.2])


@pytest.mark.parametrize("ros", [1, 2])
def test_images_without_stamps_are_named(tmp_path, ros):
    """A driver that leaves header.stamp at 0: refused by name, not one pair at t = 0."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        for n in range(3):
            bag.raw_image("/left", 0.0, "mono8", gray_pattern(n).tobytes(), log_t=1.0 + n)
            bag.raw_image("/right", 0.0, "mono8", gray_pattern(n).tobytes(), log_t=1.0 + n)
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
        record_stereo(bag, [1.0, 1.05])
    with pytest.raises(RecordingError, match=r"topic /right/camera_info: no messages"):
        BagRecording(path, "/left", "/right", "/pose", None, "/left/camera_info", "/right/camera_info")


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
            bag.image("/left", t, gray_pattern(k))
            bag.image("/right", t, gray_pattern(k))
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
            bag.image("/left", t, gray_pattern(k))
            bag.image("/right", t, gray_pattern(k))
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
            bag.image("/left", t, gray_pattern(k))
            bag.image("/right", t, gray_pattern(k))
            bag.pose("/mocap", t - 990.0, [0, 0, 1], [1, 0, 0, 0])
    spans = r"/left 1000.000 .. 1000.050, /right 1000.000 .. 1000.050, /mocap 10.000 .. 10.050"
    error = rf"\(0 kept, dropped: 2 no pose within 0.01\); header stamps \(s\): {spans}: are the topics"
    with pytest.raises(RecordingError, match=rf"no pair left after matching {error} stamped by one clock\?"):
        BagRecording(path, "/left", "/right", "/mocap", CALIB)
