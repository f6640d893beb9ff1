"""The live transform buffer (``swarm.streams.tf_buffer``) against the recordings' transform tree
(``swarm.streams.tf_tree``, what ``swarm replay bag`` uses): the same poses for the same transforms
however they arrive, and every way a lookup fails named."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.streams.tf_buffer import GAP, LOOP, NO_PATH, NOT_YET, TOO_OLD, TfBuffer, TfLookupError
from swarm.streams.tf_tree import TfTree


def _quat(yaw: float, pitch: float = 0.0) -> tuple[float, float, float, float]:
    """(w, x, y, z) of Rz(yaw) Ry(pitch)."""
    cy, sy, cp, sp = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(pitch / 2), math.sin(pitch / 2)
    return cy * cp, -sy * sp, cy * sp, sy * cp


def _transforms(rng):
    """A robot's tree: map -> odom -> base_link (dynamic, 20 Hz), base_link -> cam (static)."""
    out = []
    for k in range(40):
        t = 100.0 + 0.05 * k
        out.append(("map", "odom", t, (0.5 + 0.01 * k, -0.2, 0.0), _quat(0.1 + 0.002 * k), False))
        out.append(("odom", "base_link", t + 0.003, (0.1 * k, 0.05 * k, 0.0), _quat(0.03 * k), False))
    out.append(("base_link", "cam", 0.0, (0.1, 0.0, 0.4), _quat(-1.2, 0.3), True))
    order = rng.permutation(len(out))
    return [out[i] for i in order]


def test_poses_are_the_recording_trees_whatever_the_arrival_order():
    rng = np.random.default_rng(3)
    transforms = _transforms(rng)
    buffer, tree = TfBuffer(), TfTree()
    for parent, child, t, xyz, q, static in transforms:
        assert buffer.add(parent, child, t, xyz, q, static) is None
        tree.add(parent, child, t, xyz, q, static)
    stamps = np.sort(rng.uniform(100.01, 101.9, 60))
    rows, positions, rotations, _ = tree.chain("cam", "map").poses_at(stamps, 0.01, 0.2)
    assert len(rows) == len(stamps)
    for k, t in enumerate(stamps):
        p, r = buffer.lookup("map", "cam", t, 0.01)
        assert np.array_equal(p, positions[k]) and np.array_equal(r, rotations[k])  # bit for bit
    p, r = buffer.lookup("/map", "/cam", 100.5, 0.01)  # ROS 1's leading '/' names the same frames
    assert np.allclose(r @ r.T, np.eye(3))


def test_lookups_that_fail_say_why():
    buffer = TfBuffer(cache_s=1.0)
    for k in range(30):  # 1.5 s of samples, 1 s kept
        buffer.add("map", "base", 10.0 + 0.05 * k, (0.0, 0.0, 0.0), (1, 0, 0, 0), False)
    buffer.add("base", "cam", 0.0, (0, 0, 0.4), (1, 0, 0, 0), True)

    def reason(world, child, t, **kw):
        with pytest.raises(TfLookupError) as err:
            buffer.lookup(world, child, t, 0.01, **kw)
        return err.value.reason

    assert reason("map", "cam", 11.6) == NOT_YET  # after the newest
    buffer.lookup("map", "cam", 11.455, 0.01)  # 5 ms after the newest: its nearest sample...
    assert reason("map", "cam", 11.455, wait=True) == NOT_YET  # ...unless waiting for a later one
    assert reason("map", "cam", 10.2) == TOO_OLD  # pruned: before the last second kept
    assert reason("map", "nowhere", 11.0) == NO_PATH
    assert reason("elsewhere", "cam", 11.0) == NO_PATH
    assert reason("map", "map", 11.0) == NO_PATH
    buffer.add("base", "wheel", 12.0, (0, 0, 0), (1, 0, 0, 0), False)
    buffer.add("wheel", "base", 12.0, (0, 0, 0), (1, 0, 0, 0), False)  # base's parent is now wheel
    with pytest.raises(TfLookupError, match="cycle: base -> wheel -> base") as err:
        buffer.lookup("map", "cam", 11.0, 0.01)
    assert err.value.reason == LOOP


def test_a_gap_longer_than_the_interpolation_limit_is_named():
    buffer = TfBuffer()
    buffer.add("map", "cam", 1.0, (0, 0, 0), (1, 0, 0, 0), False)
    buffer.add("map", "cam", 2.0, (1, 0, 0), (1, 0, 0, 0), False)
    with pytest.raises(TfLookupError) as err:
        buffer.lookup("map", "cam", 1.5, 0.01)
    assert err.value.reason == GAP
    buffer.add("map", "cam", 1.55, (0.5, 0, 0), (1, 0, 0, 0), False)
    buffer.add("map", "cam", 1.45, (0.4, 0, 0), (1, 0, 0, 0), False)  # late and out of order
    p, _ = buffer.lookup("map", "cam", 1.5, 0.01)
    assert p == pytest.approx([0.45, 0, 0])


def test_unusable_transforms_are_refused_and_frames_are_bounded():
    buffer = TfBuffer(max_frames=3)
    assert buffer.add("map", "a", 1.0, (math.nan, 0, 0), (1, 0, 0, 0), False) == "unusable"
    assert buffer.add("map", "a", 1.0, (0, 0, 0), (0, 0, 0, 0), False) == "unusable"
    assert buffer.add("map", "map", 1.0, (0, 0, 0), (1, 0, 0, 0), False) == "self"
    for child in "abc":
        assert buffer.add("map", child, 1.0, (0, 0, 0), (1, 0, 0, 0), False) is None
    assert buffer.add("map", "d", 1.0, (0, 0, 0), (1, 0, 0, 0), False) == "frames"
    assert buffer.add("map", "a", 2.0, (0, 0, 0), (1, 0, 0, 0), False) is None  # a known frame still


def test_a_static_transform_keeps_its_latest_value_at_every_stamp():
    buffer = TfBuffer()
    buffer.add("base", "cam", 5.0, (0, 0, 0.3), (1, 0, 0, 0), True)
    buffer.add("base", "cam", 0.0, (0, 0, 0.4), (1, 0, 0, 0), True)  # republished: the newest wins
    for t in (0.0, 1e9):
        p, _ = buffer.lookup("base", "cam", t, 0.0)
        assert p == pytest.approx([0, 0, 0.4])
