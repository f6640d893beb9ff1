"""The left camera's pose as a chain of /tf and /tf_static transforms, composed by ``replay.bag``.

Expected poses are computed here with scipy's rotations and 4x4 matrices, not with the code tested.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from replay.bag import BagRecording

pytest.importorskip("rosbags")
from tests.rosbag_writer import BagWriter  # noqa: E402

CALIB = object()  # a calibration given: these tests read stamps and poses only
EUROC = Path(__file__).resolve().parent / "data" / "euroc_mini"
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
