"""The pose at an image's stamp (``replay.trajectory``): one rule for a bag's pose topic and for
each ``/tf`` transform of a camera's chain, checked against scipy's slerp and across both paths."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from replay.bag import BagRecording
from swarm.formats.stereo_calibration import StereoCalibration
from swarm.streams.trajectory import MAX_GAP_S, Trajectory

pytest.importorskip("rosbags")
from tests.support.rosbag_writer import BagWriter  # noqa: E402

CALIB = StereoCalibration(100.0, 100.0, 4.0, 4.0, 0.1, source="rectified test rig")  # sized by the images
TOL = 0.01
# poses at 10 Hz with a 0.3 s gap (1.3 .. 1.6), turning and climbing
POSE_TIMES = [1.0, 1.1, 1.2, 1.3, 1.6, 1.7]
# images: on a pose stamp; 5 ms after one inside a 0.1 s interval (interpolated, not that sample);
# midway; 8 ms before the first pose and 8 ms after the last (those samples); 20 ms before the first
# and after the last (none); in the gap 6 ms after its start (that sample) and in its middle (none)
IMAGE_TIMES = [1.0, 1.105, 1.15, 0.992, 1.708, 0.98, 1.72, 1.306, 1.45, 1.2]


def _pose(t: float) -> tuple[np.ndarray, np.ndarray]:
    position = np.array([2 * t, np.sin(t), 0.5 + 0.1 * t])
    rotation = Rotation.from_euler("zyx", [1.5 * t, 0.3 * np.sin(2 * t), 0.1 * t]).as_matrix()
    return position, rotation


def _wxyz(rotation: np.ndarray) -> tuple[float, ...]:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return w, x, y, z


def test_the_rule_interpolates_by_slerp_holds_a_near_sample_outside_and_drops_the_rest():
    stamps = np.array(POSE_TIMES)
    positions, rotations = zip(*(_pose(t) for t in stamps), strict=True)
    order = [3, 0, 5, 1, 4, 2]  # any order in, sorted inside
    track = Trajectory(stamps[order], np.array(positions)[order], np.array(rotations)[order])
    got = track.at(IMAGE_TIMES, TOL, MAX_GAP_S)
    slerp = Slerp(stamps[:4], Rotation.from_matrix(np.array(rotations[:4])))
    for k, t in enumerate(IMAGE_TIMES):
        if t in POSE_TIMES:  # rule 1: the sample
            i = POSE_TIMES.index(t)
            assert got.found[k] and not got.interpolated[k]
            assert np.array_equal(got.positions[k], positions[i]) and np.array_equal(
                got.rotations[k], rotations[i]
            )
        elif 1.0 < t < 1.3:  # rule 2: between two samples 0.1 s apart
            assert got.found[k] and got.interpolated[k], t
            want_p = [np.interp(t, stamps, np.array(positions)[:, i]) for i in range(3)]
            assert np.allclose(got.positions[k], want_p, atol=1e-12)
            assert np.allclose(got.rotations[k], slerp([t]).as_matrix()[0], atol=1e-9)
        else:  # rule 3 / 4: outside the span or in the 0.3 s gap, the nearest sample within TOL
            near = [i for i, s in enumerate(POSE_TIMES) if abs(s - t) <= TOL]
            assert got.found[k] == bool(near) and not got.interpolated[k], t
            if near:
                assert np.array_equal(got.positions[k], positions[near[0]])
    rows, _, _, interpolated = track.poses_at(IMAGE_TIMES, TOL)
    assert [IMAGE_TIMES[r] for r in rows] == [1.0, 1.105, 1.15, 0.992, 1.708, 1.306, 1.2]
    assert interpolated == 2
    empty = Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3))).at([1.0], TOL)
    assert not empty.found.any()


@pytest.mark.slow
@pytest.mark.parametrize("ros", [1, 2])
def test_a_pose_topic_and_a_tf_chain_of_the_same_poses_give_the_same_poses(tmp_path, ros):
    """The same samples as a PoseStamped topic (the bag's pose-topic path) and as map -> base_link
    on /tf with base_link => camera (identity) on /tf_static (the chain's path, one edge at a time):
    the same images kept and dropped, the same interpolated count, the same poses. Before, the pose
    topic took a sample within the tolerance where /tf interpolated (the image 5 ms after 1.1 s)."""
    path = tmp_path / ("b.bag" if ros == 1 else "b2")
    with BagWriter(path, ros) as bag:
        bag.transforms("/tf_static", 0.5, [("base_link", "camera", (0, 0, 0), (1, 0, 0, 0))], latched=True)
        for k, t in enumerate(sorted(IMAGE_TIMES)):
            image = np.full((8, 8), k, np.uint8)
            bag.image("/left", t, image)
            bag.image("/right", t, image)
        for t in POSE_TIMES:
            position, rotation = _pose(t)
            bag.pose("/pose", t, position, _wxyz(rotation))
            bag.transforms("/tf", t, [("map", "base_link", position, _wxyz(rotation))])
    topic = BagRecording(path, "/left", "/right", "/pose", CALIB)
    chain = BagRecording(path, "/left", "/right", "/tf", CALIB, child_frame="camera")
    assert chain.pose_frames == "camera in map (the root of its tree): map -> base_link => camera"
    assert topic.matched.describe() == chain.matched.describe() == "7 kept, dropped: 3 no pose within 0.01"
    assert topic.interpolated_poses == chain.interpolated_poses == 2
    assert np.array_equal(topic.pose_stamps, chain.pose_stamps)
    assert np.allclose(topic.positions(), chain.positions(), rtol=0, atol=1e-12)
    for a, b in zip(topic.pairs(), chain.pairs(), strict=True):
        assert a.t == b.t
        assert np.allclose(a.world_R_optical, b.world_R_optical, rtol=0, atol=1e-12)
    at = {round(p.t, 3): p for p in topic.pairs()}
    s = (1.105 - 1.1) / 0.1
    want = (1 - s) * _pose(1.1)[0] + s * _pose(1.2)[0]
    assert np.allclose(at[1.105].position, want, atol=1e-9)  # interpolated, not the 1.1 s sample
    assert np.allclose(at[1.708].position, _pose(1.7)[0], atol=1e-12)  # past the last: that sample
