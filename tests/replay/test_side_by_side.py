"""Side-by-side stereo in one image topic (``swarm replay bag --side-by-side TOPIC``): a bag written
with rosbags from real EuRoC pairs, each pair concatenated into one double-width image, replays as
the ASL folder does. The pairs: the four shipped with the tests, and the 74-pair V1_01_easy excerpt
of the project's shared data when it is found (``$SWARM_EUROC_MICRO``, or
``shared/data/euroc_v1_01_micro`` beside a folder above this one)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from replay.asl import AslRecording, RecordingError
from replay.bag import BagRecording
from swarm.formats.calibration_formats import load_stereo_calibration
from swarm.formats.stereo_calibration import StereoCalibration
from swarm.streams.frames import make_frame, rectified_camera

pytest.importorskip("rosbags")
from tests.support.euroc_replay import EUROC_MINI  # noqa: E402
from tests.support.rosbag_writer import BagWriter  # noqa: E402


def _micro() -> Path | None:
    env = os.environ.get("SWARM_EUROC_MICRO")
    places = [Path(env)] if env else []
    places += [up / "shared/data/euroc_v1_01_micro" for up in Path(__file__).resolve().parents]
    return next((p for p in places if (p / "mav0/cam0/data.csv").is_file()), None)


MICRO = _micro()
needs_micro = pytest.mark.skipif(
    MICRO is None, reason="the shared EuRoC excerpt euroc_v1_01_micro is not found"
)
DATA = [EUROC_MINI, pytest.param(MICRO, id="micro", marks=needs_micro)]
TOPICS = ["--side-by-side", "/zed/stereo/image_raw", "--pose", "/zed/left/pose"]


def _write_side_by_side(path: Path, ros: int, count: int, data: Path) -> AslRecording:
    """The ASL folder ``data``'s first ``count`` pairs as one topic of 1504 x 480 images (left | right; PNG
    compressed in ROS 2), with the left camera's PoseStamped; returns the ASL recording."""
    asl = AslRecording(data)
    with BagWriter(path, ros) as bag:
        for pair in asl.pairs(0, count):
            bag.image(
                "/zed/stereo/image_raw", pair.t, np.hstack([pair.left, pair.right]), compressed=ros == 2
            )
            w, x, y, z = _wxyz(pair.world_R_optical)  # camera to world, ROS's meaning
            bag.pose("/zed/left/pose", pair.t, pair.position, (w, x, y, z))
    return asl


def _wxyz(rotation: np.ndarray) -> tuple[float, float, float, float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return w, x, y, z


def _calibration(data: Path) -> StereoCalibration:
    return load_stereo_calibration(data / "mav0/cam0/sensor.yaml", data / "mav0/cam1/sensor.yaml")


@pytest.mark.slow
@pytest.mark.parametrize("data", DATA)
@pytest.mark.parametrize("ros", [1, 2])
def test_a_side_by_side_bag_gives_the_asl_frames(tmp_path, ros, data):
    """Each double-width image is split into the left and right camera's, checked against the
    calibration (752 x 480 each), and rectified as the ASL folder's pairs: the same frames."""
    path = tmp_path / ("zed.bag" if ros == 1 else "zed")
    asl = _write_side_by_side(path, ros, 8, data)
    count = min(8, len(asl))
    rec = BagRecording(
        path, None, None, "/zed/left/pose", _calibration(data), side_by_side="/zed/stereo/image_raw"
    )
    assert rec.matched.describe() == f"{count} kept"
    assert rec.calibration.image_size == (752, 480)
    cam = rectified_camera(rec.calibration)
    for a, b in zip(rec.pairs(), asl.pairs(0, count), strict=True):
        fa, fb = make_frame("r1", 0, a, rec.calibration, cam), make_frame("r1", 0, b, asl.calibration, cam)
        assert fa.t == pytest.approx(fb.t, abs=1e-6)
        assert np.array_equal(fa.left, fb.left) and np.array_equal(fa.right, fb.right)
        assert np.allclose(fa.pose.xyz, fb.pose.xyz, atol=1e-9) and np.allclose(
            fa.pose.ypr, fb.pose.ypr, atol=1e-9
        )


@pytest.mark.slow
@needs_micro
def test_swarm_replay_bag_side_by_side_gives_the_asl_map(tmp_path):
    """``swarm replay bag --side-by-side`` through a real server and agent: the map of ``swarm replay
    asl`` of the same two pairs, bit for bit (lockstep replays are deterministic)."""
    from swarm.formats.map_file import load_map
    from tests.support.euroc_replay import swarm_replay

    bag = tmp_path / "zed.bag"
    _write_side_by_side(bag, 1, 2, MICRO)
    calib = [
        "--calib-left",
        str(MICRO / "mav0/cam0/sensor.yaml"),
        "--calib-right",
        str(MICRO / "mav0/cam1/sensor.yaml"),
    ]
    swarm_replay(["asl", str(MICRO), "--frames", "2"], tmp_path / "asl")
    config = ["--config", str(tmp_path / "asl/config.yaml")]  # the workspace of the whole excerpt
    swarm_replay(["bag", str(bag), *TOPICS, *calib, *config], tmp_path / "bag")
    got, want = load_map(tmp_path / "bag/map.npz"), load_map(tmp_path / "asl/map.npz")
    assert np.array_equal(got.lam, want.lam) and np.array_equal(got.eta, want.eta)
    assert want.known_mask().sum() > 1000


def test_side_by_side_mistakes_are_named_before_anything_starts(tmp_path, capsys):
    """An odd-width image, --side-by-side with --left, or --left alone: one error line, no run."""
    from swarm.cli import main

    bag = tmp_path / "odd.bag"
    with BagWriter(bag, 1) as writer:
        for k in range(2):
            writer.image("/stereo", 1.0 + 0.05 * k, np.zeros((6, 15), np.uint8))
            writer.pose("/pose", 1.0 + 0.05 * k, (0, 0, 1), (1, 0, 0, 0))
    rig = StereoCalibration(100.0, 100.0, 4.0, 3.0, 0.1, source="rig")
    with pytest.raises(RecordingError, match=r"odd.bag: topic /stereo: a side-by-side pair is a double-width "
                       r"image; 15x6 has an odd width"):  # fmt: skip
        BagRecording(bag, None, None, "/pose", rig, side_by_side="/stereo")
    out = tmp_path / "run"
    for args, error in (
        (
            ["--side-by-side", "/stereo", "--left", "/stereo"],
            "as --left and --right or as --side-by-side, not both",
        ),
        (["--left", "/stereo"], "give both image topics (--left, --right) or --side-by-side"),
    ):
        rc = main(
            ["replay", "bag", str(bag), *args, "--pose", "/pose", "--calib-left", "x.yaml", "--out", str(out)]
        )
        err = capsys.readouterr().err
        assert rc == 2 and error in err, err
        assert not out.exists()
