"""ROS 1 and ROS 2 bags, written with rosbags' writers, read back by ``replay.bag``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.streams.frames import make_frame, rectified_camera
from tests.support.euroc_bags import EUROC, _write_euroc_bag

pytest.importorskip("rosbags")
from tests.support.rosbag_writer import BagWriter  # noqa: E402


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


@pytest.mark.slow
def test_euroc_bags_replayed_give_the_asl_map(tmp_path, euroc_asl_run):
    """ROS 1 bag (calibration from the sensor.yaml files) and ROS 2 bag (from its CameraInfo topics)
    through ``swarm replay bag``: the same map as ``swarm replay asl`` of the same pairs."""
    from swarm.formats.map_file import load_map
    from tests.support.euroc_replay import REPLAY_FRAMES, swarm_replay

    topics = ["--left", "/cam0/image_raw", "--right", "/cam1/image_raw", "--pose", "/cam0/pose"]
    runs = {
        "ros1": ["--calib-left", str(EUROC / "mav0/cam0/sensor.yaml"),
                 "--calib-right", str(EUROC / "mav0/cam1/sensor.yaml")],
        "ros2": ["--left-info", "/cam0/camera_info", "--right-info", "/cam1/camera_info"],
    }  # fmt: skip
    want = load_map(euroc_asl_run / "map.npz")
    known = want.known_mask()
    assert known.sum() > 5_000
    for name, calib in runs.items():
        bag = tmp_path / ("euroc.bag" if name == "ros1" else "euroc-ros2")
        _write_euroc_bag(bag, 1 if name == "ros1" else 2)
        out = tmp_path / name
        swarm_replay(["bag", str(bag), *topics, *calib, "--frames", str(REPLAY_FRAMES)], out)
        got = load_map(out / "map.npz")
        assert got.grid.matches(want.grid), name
        assert np.array_equal(got.known_mask(), known), name
        assert np.allclose(got.mean(known), want.mean(known), rtol=1e-6, atol=1e-7), name
        assert np.allclose(got.sigma(known) ** 2, want.sigma(known) ** 2, rtol=1e-6, atol=1e-9), name
        # Exact by design: bit-equal rectified frames, lockstep (each frame fused before the next
        # leaves), a deterministic agent, and an agent that exits only once the server holds all
        # its deltas (its shutdown flush included), applied in the order sent.
        assert np.array_equal(got.lam, want.lam) and np.array_equal(got.eta, want.eta), name
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["frames"] == REPLAY_FRAMES and metrics["unanswered"] == 0, name


def test_calibration_for_another_image_size_is_refused_before_the_run(tmp_path, capsys):
    """A calibration file made for other images (here a camera_calibration pair for 640 x 480 on
    EuRoC's 752 x 480) is one error line naming it, before any process starts; a rectified rig
    that states no size takes the images'."""
    from swarm.cli import main

    bag = tmp_path / "euroc.bag"
    _write_euroc_bag(bag, 1)
    rig = tmp_path / "rig.yaml"
    rig.write_text("fx: 436.2\nfy: 436.2\ncx: 364.4\ncy: 256.8\nbaseline: 0.11\nwidth: 640\nheight: 480\n")
    topics = ["--left", "/cam0/image_raw", "--right", "/cam1/image_raw", "--pose", "/cam0/pose"]
    out = tmp_path / "run"
    rc = main(["replay", "bag", str(bag), *topics, "--calib-left", str(rig), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    # the bag's reader checks its first images when it opens the bag (replay.frames.fit_image_size)
    assert "topic /cam0/image_raw: images are 752x480, the calibration" in err
    assert "rig.yaml) is for 640x480" in err
    assert not out.exists()
    rig.write_text("fx: 436.2\nfy: 436.2\ncx: 364.4\ncy: 256.8\nbaseline: 0.11\n")
    rec = BagRecording(bag, "/cam0/image_raw", "/cam1/image_raw", "/cam0/pose", load_stereo_calibration(rig))
    assert rec.calibration.image_size == (752, 480) and rec.calibration.baseline == 0.11


def test_calibration_files_and_info_topics_together_are_refused(tmp_path, capsys) -> None:
    """Both a --calib-left file and --left-info topics: one error line, before anything starts."""
    from swarm.cli import main

    bag = tmp_path / "euroc.bag"
    _write_euroc_bag(bag, 1)
    rig = tmp_path / "rig.yaml"
    rig.write_text("fx: 436.2\nfy: 436.2\ncx: 364.4\ncy: 256.8\nbaseline: 0.11\n")
    topics = ["--left", "/cam0/image_raw", "--right", "/cam1/image_raw", "--pose", "/cam0/pose"]
    info = ["--left-info", "/cam0/camera_info", "--right-info", "/cam1/camera_info"]
    out = tmp_path / "run"
    rc = main(["replay", "bag", str(bag), *topics, *info, "--calib-left", str(rig), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "either as files (--calib-left, --calib-right) or as CameraInfo topics" in err
    assert not out.exists()


def test_opencv_stereo_calib_files_without_a_size_take_the_bags_image_size(tmp_path) -> None:
    """OpenCV's stereo_calib sample writes intrinsics.yml + extrinsics.yml with no image size:
    `swarm replay bag --calib-left intrinsics.yml --calib-right extrinsics.yml` takes the bag's
    752x480 and rectifies as the EuRoC sensor.yaml pair does."""
    import argparse

    import yaml

    from swarm.cli.replay import _open_bag
    from swarm.formats.calibration_formats import KalibrCamera

    bag = tmp_path / "euroc.bag"
    _write_euroc_bag(bag, 1)
    cam0, cam1 = (KalibrCamera.load(EUROC / f"mav0/cam{i}/sensor.yaml") for i in (0, 1))
    right_from_left = np.linalg.inv(cam1.body_from_camera) @ cam0.body_from_camera
    (tmp_path / "intrinsics.yml").write_text(
        yaml.safe_dump(
            {"M1": cam0.k.tolist(), "D1": cam0.d.tolist(), "M2": cam1.k.tolist(), "D2": cam1.d.tolist()}
        )
    )
    (tmp_path / "extrinsics.yml").write_text(
        yaml.safe_dump({"R": right_from_left[:3, :3].tolist(), "T": right_from_left[:3, 3].tolist()})
    )
    args = argparse.Namespace(
        bag=bag, left="/cam0/image_raw", right="/cam1/image_raw", pose="/cam0/pose", left_info=None,
        right_info=None, child_frame=None, tolerance=0.01, calib_left=tmp_path / "intrinsics.yml",
        calib_right=tmp_path / "extrinsics.yml", world_frame=None, tf_static=None, side_by_side=None,
    )  # fmt: skip
    recording = _open_bag(args)
    want = load_stereo_calibration(EUROC / "mav0/cam0/sensor.yaml", EUROC / "mav0/cam1/sensor.yaml")
    assert recording.calibration.image_size == (752, 480)
    for field in ("fx", "fy", "cx", "cy", "baseline", "cx_right"):
        assert getattr(recording.calibration, field) == pytest.approx(getattr(want, field), rel=1e-9)
