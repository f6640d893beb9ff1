"""The left camera's pose as a chain of /tf and /tf_static transforms, composed by ``replay.bag``.

Expected poses are computed here with scipy's rotations and 4x4 matrices, not with the code tested.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from replay.asl import RecordingError
from replay.bag import BagRecording
from swarm.formats.stereo_calibration import StereoCalibration
from tests.support.paths import TEST_DATA

pytest.importorskip("rosbags")
from tests.support.rosbag_writer import BagWriter  # noqa: E402

# a rectified rig that states no image size: it takes the images' (these tests read images, stamps, poses)
CALIB = StereoCalibration(100.0, 100.0, 8.0, 6.0, 0.1, source="rectified test rig")
EUROC = TEST_DATA / "euroc_mini"
OPTICAL = (0.5, -0.5, 0.5, -0.5)  # camera_link -> optical frame: z forward, x right, y down (w, x, y, z)


def _bag(tmp_path: Path, ros: int) -> Path:
    return tmp_path / ("b.bag" if ros == 1 else "b2")


def _matrix(xyz, wxyz) -> np.ndarray:
    """X_parent = T X_child of a transform (translation, quaternion w x y z)."""
    w, x, y, z = wxyz
    t = np.eye(4)
    t[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    t[:3, 3] = xyz
    return t


def _quat(rotation: np.ndarray) -> tuple[float, ...]:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return w, x, y, z


def _stereo(bag: BagWriter, times) -> None:
    for k, t in enumerate(times):
        image = np.full((8, 8), k % 250, np.uint8)
        bag.image("/left", t, image)
        bag.image("/right", t, image)


def _odom(t):  # map -> odom: a slow drift correction
    return (0.1 * t, -0.05 * t, 0.0), _quat(Rotation.from_euler("z", 0.02 * t).as_matrix())


def _base(t):  # odom -> base_link: driving a curve, pitching a little
    return (2 * t, np.sin(t), 0.1), _quat(
        Rotation.from_euler("zy", [0.8 * t, 0.1 * np.sin(3 * t)]).as_matrix()
    )


MOUNT = ((0.3, 0.0, 0.5), _quat(Rotation.from_euler("y", 0.2).as_matrix()))  # base_link -> camera_link


def _write_chain(path: Path, ros: int, images, odom_times, base_times, slash: str = "") -> None:
    """map -> odom and odom -> base_link on /tf, base_link -> camera_link -> camera_optical once
    on a latched /tf_static (ROS 1 frame ids with a leading '/' when ``slash``)."""
    with BagWriter(path, ros) as bag:
        static = [
            (f"{slash}base_link", "camera_link", *MOUNT),
            ("camera_link", "camera_optical", (0, 0, 0), OPTICAL),
        ]
        bag.transforms("/tf_static", min(images) - 0.5, static, latched=True)
        _stereo(bag, images)
        for t in odom_times:
            bag.transforms("/tf", t, [(f"{slash}map", f"{slash}odom", *_odom(t))])
        for t in base_times:
            bag.transforms("/tf", t, [("odom", f"{slash}base_link", *_base(t))])


def _expected(t: float, odom_times, base_times) -> np.ndarray:
    """world_T_camera at t: each dynamic transform interpolated (linear, slerp), then 4x4 products."""

    def at(times, fn):
        times = np.asarray(times)
        xyz = np.array([fn(s)[0] for s in times])
        w, x, y, z = np.array([fn(s)[1] for s in times]).T
        slerp = Slerp(times, Rotation.from_quat(np.c_[x, y, z, w]))
        s = min(max(t, times[0]), times[-1])  # past the last sample: its value
        out = np.eye(4)
        out[:3, :3] = slerp([s]).as_matrix()[0]
        out[:3, 3] = [np.interp(s, times, xyz[:, i]) for i in range(3)]
        return out

    return at(odom_times, _odom) @ at(base_times, _base) @ _matrix(*MOUNT) @ _matrix((0, 0, 0), OPTICAL)


@pytest.mark.parametrize("ros", [1, 2])
def test_a_tf_chain_gives_the_product_of_its_transforms(tmp_path, ros):
    """map -> odom (20 Hz) -> base_link (20 Hz) on /tf, base_link -> camera_link -> camera_optical on
    /tf_static: each image's pose is the product of the chain's matrices at its stamp."""
    path = _bag(tmp_path, ros)
    times = [1.0 + 0.05 * k for k in range(10)]
    _write_chain(path, ros, times, times, times, slash="/" if ros == 1 else "")
    rec = BagRecording(path, "/left", "/right", "/tf", CALIB, child_frame="camera_optical")
    chain = "map -> odom -> base_link => camera_link => camera_optical"
    assert rec.pose_frames == f"camera_optical in map (the root of its tree): {chain}"
    assert rec.matched.describe() == "10 kept"
    pairs = list(rec.pairs())
    assert [p.t for p in pairs] == pytest.approx(times)
    for pair in pairs:
        want = _expected(pair.t, times, times)
        assert np.allclose(pair.position, want[:3, 3], atol=1e-9)
        assert np.allclose(pair.world_R_optical, want[:3, :3], atol=1e-9)
    # --world-frame odom: the same chain without map -> odom
    rec = BagRecording(
        path, "/left", "/right", "/tf", CALIB, child_frame="/camera_optical", world_frame="odom"
    )
    assert rec.pose_frames.startswith("camera_optical in odom (--world-frame): odom -> base_link =>")
    for pair in rec.pairs():
        want = np.linalg.inv(_matrix(*_odom(pair.t))) @ _expected(pair.t, times, times)
        assert np.allclose(pair.position, want[:3, 3], atol=1e-9)
        assert np.allclose(pair.world_R_optical, want[:3, :3], atol=1e-9)


@pytest.mark.parametrize("ros", [1, 2])
def test_dynamic_transforms_are_interpolated_at_the_image_stamps(tmp_path, ros):
    """map -> odom at 20 Hz and odom -> base_link at 30 Hz, a 30 Hz camera on neither's stamps: each
    transform is interpolated at the image's stamp (straight line, slerp). An image past base_link's
    last sample by less than the tolerance takes that sample; one before the first samples or in a
    gap of more than 0.2 s gets no pose."""
    path = _bag(tmp_path, ros)
    odom_times = [1.0 + 0.05 * k for k in range(21)]  # 1.0 .. 2.0
    base_times = [1.01 + k / 30 for k in range(15)] + [1.72 + k / 30 for k in range(9)]  # gap 1.477 .. 1.72
    images = [1.024 + k / 30 for k in range(29)] + [0.95, base_times[-1] + 0.005]
    _write_chain(path, ros, images, odom_times, base_times)
    rec = BagRecording(path, "/left", "/right", "/tf", CALIB, child_frame="camera_optical")
    kept = [t for t in sorted(images) if 1.01 < t < base_times[14] or 1.72 < t < base_times[-1] + 0.01]
    assert len(kept) == 23  # 14 before the gap, 8 after it, 1 past the last base_link sample
    assert (
        rec.matched.describe() == f"{len(kept)} kept, dropped: {len(images) - len(kept)} no pose within 0.01"
    )
    assert rec.interpolated_poses == len(kept)
    pairs = list(rec.pairs())
    assert [p.t for p in pairs] == pytest.approx(kept)
    for pair in pairs:
        want = _expected(pair.t, odom_times, base_times)
        assert np.allclose(pair.position, want[:3, 3], rtol=0, atol=1e-6)
        assert np.allclose(pair.world_R_optical, want[:3, :3], rtol=0, atol=1e-6)


@pytest.mark.parametrize("ros", [1, 2])
def test_the_cameras_own_transform_on_tf_is_read_as_before(tmp_path, ros):
    """world -> cam0_optical on /tf (10 Hz, turning, one NaN sample), other frames on /tf and
    /tf_static: the poses, the interpolation and the counts are those of the same poses as a
    PoseStamped topic (whose reading this change leaves alone), as they were before chains."""
    path = _bag(tmp_path, ros)
    images = [0.95, 1.0, 1.03, 1.05, 1.1, 1.15, 1.2, 1.5, 1.55]
    poses = [(1.0, (0, 0, 1), (1, 0, 0, 0)), (1.1, (2, 0, 1), (0.5**0.5, 0, 0, 0.5**0.5)),
             (1.2, (float("nan"), 0, 1), (1, 0, 0, 0)), (1.3, (2, 1, 1), (0.5, 0.5, 0.5, 0.5)),
             (1.5, (2, 0, 1), (0.5**0.5, 0, 0.5**0.5, 0))]  # fmt: skip
    with BagWriter(path, ros) as bag:
        bag.transforms("/tf_static", 0.9, [("base_link", "camera_link", *MOUNT)], latched=True)
        _stereo(bag, images)
        for t, xyz, q in poses:
            bag.transforms(
                "/tf", t, [("odom", "base_link", (t, 0, 0), (1, 0, 0, 0)), ("world", "cam0_optical", xyz, q)]
            )
            bag.pose("/pose", t, xyz, q)
    rec = BagRecording(path, "/left", "/right", "/tf", CALIB, child_frame="cam0_optical")
    want = BagRecording(path, "/left", "/right", "/pose", CALIB)
    assert rec.pose_frames == "cam0_optical in world (the root of its tree): world -> cam0_optical"
    assert rec.matched.describe() == want.matched.describe()
    assert "1 unusable pose message" in rec.matched.describe()
    assert rec.interpolated_poses == want.interpolated_poses == 4  # 1.03, 1.05, 1.15, 1.2
    assert np.array_equal(rec.pose_stamps, want.pose_stamps)
    assert np.array_equal(rec.pose_positions, want.pose_positions)
    assert np.array_equal(rec.pose_rotations, want.pose_rotations)
    assert np.array_equal(rec.matched.others["pose"], want.matched.others["pose"])


def _write_tree(path: Path, ros: int, extra=(), static_extra=()) -> None:
    """The chain map -> odom -> base_link (/tf) => camera_link => camera_optical (/tf_static), and
    ``extra`` transforms on /tf, ``static_extra`` on /tf_static."""
    one = ((0, 0, 0), (1, 0, 0, 0))
    with BagWriter(path, ros) as bag:
        static = [("base_link", "camera_link", *MOUNT), ("camera_link", "camera_optical", (0, 0, 0), OPTICAL)]
        bag.transforms("/tf_static", 0.5, static + [(p, c, *one) for p, c in static_extra], latched=True)
        _stereo(bag, [1.0, 1.05])
        for t in (1.0, 1.05):
            chain = [("map", "odom", *_odom(t)), ("odom", "base_link", *_base(t))]
            bag.transforms("/tf", t, chain + [(p, c, *one) for p, c in extra])
            bag.pose("/pose", t, *one)


@pytest.mark.parametrize("ros", [1, 2])
def test_trees_that_do_not_give_the_cameras_pose_are_named(tmp_path, ros):
    """A child frame not in the tree, a world frame not above it, a frame with two parents, a cycle,
    a transform on both topics: one error naming the frames, when the bag is opened."""
    where = r"topic /tf \+ /tf_static: "
    cases = {
        "missing": ({}, {"child_frame": "cam9"}, r"frame 'cam9' is not in the transform tree "
                    r"\(frames: base_link, camera_link, camera_optical, map, odom\)"),
        "not above": ({"extra": [("map", "gps")]}, {"world_frame": "gps"}, r"frame 'gps' is not an "
                      r"ancestor of 'camera_optical' \(its ancestors: camera_link, base_link, odom, map\)"),
        "two parents": ({"extra": [("map", "base_link")]}, {}, r"frame 'base_link' has two parents, "
                        r"'map' and 'odom' \(tf allows one\)"),
        "cycle": ({"extra": [("camera_optical", "map")]}, {}, r"the transforms make a cycle: camera_optical "
                  r"-> map -> odom -> base_link -> camera_link -> camera_optical"),
        "both topics": ({"static_extra": [("odom", "base_link")]}, {}, r"transform odom -> base_link is on "
                        r"both /tf and /tf_static"),
        "root": ({}, {"child_frame": "/map"}, r"frame 'map' has no parent: it is a root, not a camera"),
    }  # fmt: skip
    for name, (tree, options, error) in cases.items():
        path = _bag(tmp_path / name, ros)
        path.parent.mkdir()
        _write_tree(path, ros, **tree)
        options = {"child_frame": "camera_optical", **options}
        with pytest.raises(RecordingError, match=where + error):
            BagRecording(path, "/left", "/right", "/tf", CALIB, **options)
    path = _bag(tmp_path / "missing", ros)
    with pytest.raises(
        RecordingError,
        match=r"--tf-static /static is not in the bag \(topics: /left, /pose, /right, /tf, /tf_static\)",
    ):
        BagRecording(path, "/left", "/right", "/tf", CALIB, child_frame="camera_optical", tf_static="/static")
    with pytest.raises(RecordingError, match=r"--world-frame and --tf-static are for a /tf pose topic"):
        BagRecording(path, "/left", "/right", "/pose", CALIB, world_frame="map")


def test_swarm_replay_bag_names_a_bad_world_frame_before_anything_starts(tmp_path, capsys):
    from swarm.cli import main

    bag = tmp_path / "b.bag"
    _write_tree(bag, 1)
    rig = tmp_path / "rig.yaml"
    rig.write_text("fx: 10\nfy: 10\ncx: 4\ncy: 4\nbaseline: 0.1\n")
    out = tmp_path / "run"
    args = ["replay", "bag", str(bag), "--left", "/left", "--right", "/right", "--pose", "/tf",
            "--calib-left", str(rig), "--child-frame", "camera_optical", "--world-frame", "base",
            "--out", str(out)]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "b.bag: topic /tf + /tf_static: frame 'base' is not an ancestor of 'camera_optical'" in err
    assert not out.exists()


@pytest.mark.parametrize("ros", [1, 2])
def test_euroc_with_its_camera_on_a_tf_chain_gives_the_asl_poses(tmp_path, ros):
    """The EuRoC excerpt with cam0's ground truth split as a robot publishes it: world -> odom ->
    body on /tf at each image, body => cam0 (its sensor.yaml T_BS) once on /tf_static. The replayed
    poses are the ASL replay's."""
    from replay.asl import AslRecording
    from swarm.formats.calibration_formats import KalibrCamera

    asl = AslRecording(EUROC)
    body_T_cam = KalibrCamera.load(EUROC / "mav0/cam0/sensor.yaml").body_from_camera
    world_T_odom = _matrix((1.0, 2.0, 0.0), _quat(Rotation.from_euler("z", 30, degrees=True).as_matrix()))
    gt = np.loadtxt(EUROC / "mav0/cam0_groundtruth/data.csv", delimiter=",", skiprows=1)
    path = _bag(tmp_path, ros)
    with BagWriter(path, ros) as bag:
        mount = (body_T_cam[:3, 3], _quat(body_T_cam[:3, :3]))
        for k, pair in enumerate(asl.pairs()):
            if k == 0:
                bag.transforms("/tf_static", pair.t, [("body", "cam0", *mount)], latched=True)
            bag.image("/cam0/image_raw", pair.t, pair.left)
            bag.image("/cam1/image_raw", pair.t, pair.right)
            row = gt[np.argmin(np.abs(gt[:, 0] * 1e-9 - pair.t))]
            w, x, y, z = row[4:8]  # camera-from-world: its conjugate turns camera vectors into the world's
            world_T_cam = _matrix(row[1:4], (w, -x, -y, -z))
            odom_T_body = np.linalg.inv(world_T_odom) @ world_T_cam @ np.linalg.inv(body_T_cam)
            bag.transforms(
                "/tf",
                pair.t,
                [
                    ("world", "odom", world_T_odom[:3, 3], _quat(world_T_odom[:3, :3])),
                    ("odom", "body", odom_T_body[:3, 3], _quat(odom_T_body[:3, :3])),
                ],
            )
    rec = BagRecording(path, "/cam0/image_raw", "/cam1/image_raw", "/tf", CALIB, child_frame="cam0")
    assert rec.pose_frames == "cam0 in world (the root of its tree): world -> odom -> body => cam0"
    assert len(rec) == len(asl) and rec.matched.describe() == f"{len(asl)} kept"
    for got, want in zip(rec.pairs(), asl.pairs(), strict=True):
        assert got.t == pytest.approx(want.t, abs=1e-6)
        assert np.allclose(got.position, want.position, rtol=0, atol=1e-6)
        assert np.allclose(got.world_R_optical, want.world_R_optical, rtol=0, atol=1e-6)
