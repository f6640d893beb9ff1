"""ROS 1 and ROS 2 bags, written with rosbags' writers, read back by ``replay.bag``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from replay.frames import make_frame, rectified_camera
from swarm.formats.calibration_formats import load_stereo_calibration

pytest.importorskip("rosbags")
from tests.rosbag_writer import BagWriter  # noqa: E402

EUROC = Path(__file__).resolve().parent / "data" / "euroc_mini"  # four real pairs (its README)


@pytest.mark.parametrize("ros", [1, 2])
def test_missing_topic_is_named(tmp_path, ros):
    path = tmp_path / ("b.bag" if ros == 1 else "b2")
    with BagWriter(path, ros) as bag:
        bag.image("/left", 1.0, np.zeros((8, 8), np.uint8))
        bag.pose("/pose", 1.0, [0, 0, 1], [1, 0, 0, 0])
    with pytest.raises(
        RecordingError, match=r"topic /right \(right\) is not in the bag \(topics: /left, /pose\)"
    ):
        BagRecording(path, "/left", "/right", "/pose", calibration=object())


def _mission_calibration():
    return load_stereo_calibration(EUROC / "mav0/cam0/sensor.yaml", EUROC / "mav0/cam1/sensor.yaml")


@pytest.mark.parametrize("ros", [1, 2])
def test_euroc_written_to_a_bag_gives_the_asl_frames(tmp_path, ros):
    from replay.asl import AslRecording

    asl = AslRecording(EUROC)
    n = 4
    path = tmp_path / ("euroc.bag" if ros == 1 else "euroc")
    gt = np.loadtxt(EUROC / "mav0/cam0_groundtruth/data.csv", delimiter=",", skiprows=1)
    with BagWriter(path, ros) as bag:
        for k, pair in enumerate(asl.pairs(0, n)):
            if k == 2:
                continue  # one right image lost: the pair is dropped and counted
            bag.image("/cam1/image_raw", pair.t, pair.right, compressed=(ros == 2))
        for pair in asl.pairs(0, n):
            bag.image("/cam0/image_raw", pair.t, pair.left)
            row = gt[np.argmin(np.abs(gt[:, 0] * 1e-9 - pair.t))]
            w, x, y, z = row[4:8]
            bag.pose("/cam0/pose", pair.t, row[1:4], (w, -x, -y, -z))  # world-from-camera: conjugate
    rec = BagRecording(path, "/cam0/image_raw", "/cam1/image_raw", "/cam0/pose", _mission_calibration())
    assert len(rec) == n - 1
    assert rec.matched.describe() == f"{n - 1} kept, dropped: 1 no right image within 0.01"
    cam = rectified_camera(rec.calibration)
    want = [p for k, p in enumerate(asl.pairs(0, n)) if k != 2]
    for a, b in zip(rec.pairs(), want, strict=True):
        fa = make_frame("r1", 0, a, rec.calibration, cam)
        fb = make_frame("r1", 0, b, asl.calibration, cam)
        assert fa.t == pytest.approx(fb.t, abs=1e-6)
        assert np.array_equal(fa.left, fb.left) and np.array_equal(fa.right, fb.right)
        assert np.allclose(fa.pose.xyz, fb.pose.xyz) and np.allclose(fa.pose.ypr, fb.pose.ypr, atol=1e-9)
