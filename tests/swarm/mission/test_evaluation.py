"""Measures of docs/design.md section 7 against hand-computed examples."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.map.grid import Grid
from swarm.mission.evaluation import (
    coverage_mae,
    entropy_split,
    explored_fraction,
    first_seen_times,
    mission_time,
    observable_mask,
    occupancy_f1,
    overlap_fraction,
    overlap_up_to,
    overlaps_during_mission,
    path_length,
)


def test_occupancy_f1_hand_example():
    exp = np.array([0.9, 0.8, 0.2, 0.6, 0.1, 0.5, 0.9])
    true = np.array([1.0, 0.7, 1.0, 0.0, 0.0, 0.9, 0.0])
    mask = np.array([True, True, True, True, True, True, False])  # the last (an fp) is left out
    # predicted (> 0.5): 1 1 0 1 0 0 ; true (> 0.5): 1 1 1 0 0 1 -> tp 2, fp 1, fn 2
    r = occupancy_f1(exp, true, mask)
    assert (r["tp"], r["fp"], r["fn"], r["n"]) == (2, 1, 2, 6)
    assert r["precision"] == pytest.approx(2 / 3)
    assert r["recall"] == pytest.approx(2 / 4)
    assert r["f1"] == pytest.approx(2 * (2 / 3) * 0.5 / (2 / 3 + 0.5))


def test_occupancy_f1_shapes_mix_and_empty_cases():
    exp = np.full((2, 2, 2), 0.1)
    true = np.zeros(8)
    mask = np.ones((2, 2, 2), bool)
    assert occupancy_f1(exp, true, mask)["f1"] == 1.0  # no positives on either side
    true[3] = 1.0
    r = occupancy_f1(exp, true, mask)
    assert (r["f1"], r["recall"], r["fn"]) == (0.0, 0.0, 1)
    assert occupancy_f1(exp, true, np.zeros(8, bool))["n"] == 0


def test_coverage_mae_direct():
    rng = np.random.default_rng(1)
    exp, true = rng.random(50), rng.random(50)
    mask = rng.random(50) > 0.4
    assert coverage_mae(exp, true, mask) == pytest.approx(np.abs(exp - true)[mask].mean())
    assert np.isnan(coverage_mae(exp, true, np.zeros(50, bool)))


def test_observable_mask_thick_block():
    grid = Grid((0.0, 0.0, 0.0), 0.1, (8, 8, 8))
    cov = np.zeros(grid.shape, np.float32)
    cov[2:6, 2:6, 2:6] = 1.0  # a 4 x 4 x 4 block floating in the grid
    mask = observable_mask(cov, grid)
    assert mask.shape == grid.shape
    assert not mask[3:5, 3:5, 3:5].any()  # its 2 x 2 x 2 core
    block = np.zeros(grid.shape, bool)
    block[2:6, 2:6, 2:6] = True
    assert np.count_nonzero(mask & block) == 64 - 8  # its surface
    assert mask[~block].all()  # all the free space


def test_observable_mask_grid_border_floor_and_workspace():
    # A block standing on the floor, through the top of the grid; the grid reaches z < 0.
    grid = Grid((0.0, 0.0, -0.2), 0.1, (6, 6, 6))  # z from -0.2 to 0.4
    cov = np.zeros(grid.shape, np.float32)
    cov[:, :, :2] = 1.0  # the ground
    cov[1:5, 1:5, :] = 1.0  # the block
    mask = observable_mask(cov, grid)
    assert not mask[:, :, :2].any()  # below the floor
    assert not mask[2:4, 2:4, 2:].any()  # core: neighbours outside the grid count as covered
    assert mask[1, 2, 3] and not mask[2, 2, 5]
    assert observable_mask(cov, grid, floor_z=None)[0, 0, 1]  # the ground's surface
    # voxels whose centre is outside the workspace are left out
    cut = observable_mask(cov, grid, workspace=((0, 0, 0), (0.5, 0.6, 0.4)))
    assert not cut[5].any() and cut[4, 0, 2]


def test_explored_fraction():
    obs = np.array([True, True, True, True, False])
    known = np.array([True, False, True, False, True])
    assert explored_fraction(known, obs) == pytest.approx(0.5)
    assert explored_fraction(known, np.zeros(5, bool)) == 0.0


def test_overlap_fraction():
    a = np.array([1, 1, 0, 0, 0, 0], bool)
    b = np.array([0, 1, 1, 0, 0, 0], bool)
    c = np.array([0, 1, 0, 1, 0, 0], bool)
    assert overlap_fraction({"a": a, "b": b}) == pytest.approx(1 / 3)
    assert overlap_fraction({"a": a, "b": b, "c": c}) == pytest.approx(1 / 4)
    assert overlap_fraction({"a": a}) == 0.0
    assert overlap_fraction({"a": np.zeros(6, bool)}) == 0.0
    assert overlap_fraction({}) == 0.0


NEVER = np.iinfo(np.int32).max


def test_overlap_up_to_counts_what_was_shared_by_then():
    first_delta = {
        "a": np.array([1, 2, NEVER, NEVER, 9]),
        "b": np.array([NEVER, 5, 3, NEVER, 9]),
    }
    # by delta 3: a has voxels 0, 1; b has voxel 2 -> no overlap yet
    assert overlap_up_to(first_delta, 3) == 0.0
    # by delta 5: voxel 1 is both robots' -> 1 of 3
    assert overlap_up_to(first_delta, 5) == pytest.approx(1 / 3)
    # at the end: voxels 1 and 4 of 4 observed ones, the same as overlap_fraction of the masks
    masks = {r: n != NEVER for r, n in first_delta.items()}
    assert overlap_fraction(masks) == pytest.approx(2 / 4)
    assert overlap_up_to(first_delta, NEVER - 1) == pytest.approx(2 / 4)


def test_first_seen_times_reads_each_voxels_first_delta_off_the_curve():
    curve_t = np.array([0.0, 0.5, 0.5, 1.0, 7.5])  # delta n was applied at curve_t[n]
    times = first_seen_times(np.array([1, 4, NEVER, 3]), curve_t, never=NEVER)
    assert times.tolist() == [0.5, 7.5, np.inf, 1.0]


def test_overlaps_during_mission_leave_out_the_flush_that_reaches_the_threshold():
    # deltas 1-3 pass the agents' utility filter; delta 4 is r1's end-of-work flush, which
    # brings the team entropy to H_th (20); delta 5 is r2's shutdown flush, at the same time
    curve = [(0.0, 100.0), (1.0, 80.0), (2.0, 59.0), (3.0, 30.0), (4.0, 20.0), (4.0, 19.0)]
    first_delta = {
        "r1": np.array([1, 3, 4, NEVER, 4]),
        "r2": np.array([NEVER, 2, 5, 5, NEVER]),
    }
    out = overlaps_during_mission(first_delta, curve, threshold=20.0)
    # halfway from 100 to 20 is 60: first reached at delta 2 (t = 2); by then r1 had voxel 0,
    # r2 voxel 1 -> no overlap
    assert out["halfway_time_s"] == 2.0
    assert out["overlap_halfway"] == 0.0
    # before H_th (deltas 1-3): r1 has voxels 0 and 1, r2 has 1 -> 1 of 2
    assert out["overlap_before_threshold"] == pytest.approx(1 / 2)
    # the flushes would add voxel 2 (both robots'), 3 and 4 -> 2 of 5, as the headline counts
    assert overlap_up_to(first_delta, 5) == pytest.approx(2 / 5)
    masks = {r: n != NEVER for r, n in first_delta.items()}
    assert overlap_fraction(masks) == pytest.approx(2 / 5)
    # a mission that never reached H_th, or never got halfway
    assert overlaps_during_mission(first_delta, curve, threshold=0.0)["overlap_before_threshold"] is None
    never_half = overlaps_during_mission(first_delta, curve[:2], threshold=0.0)
    assert never_half == {"halfway_time_s": None, "overlap_halfway": None, "overlap_before_threshold": None}
    assert overlaps_during_mission(first_delta, [], threshold=0.0)["halfway_time_s"] is None


def test_mission_time_first_crossing():
    curve = [(0.0, 100.0), (1.0, 50.0), (2.0, 30.0), (3.0, 40.0), (4.0, 20.0)]
    assert mission_time(curve, 30.0) == 2.0  # H <= H_th counts
    assert mission_time(curve, 35.0) == 2.0
    assert mission_time(curve, 25.0) == 4.0
    assert mission_time(curve, 10.0) is None
    assert mission_time([], 10.0) is None


def test_entropy_split_hand_example():
    h = np.array([1.0, 2.0, 3.0, 4.0])
    obs = np.array([True, True, False, False])
    s = entropy_split(h, obs, 7.0)
    assert s["initial_bits"] == 28.0 and s["final_bits"] == 10.0
    assert s["final_observable_bits"] == 3.0 and s["final_unobservable_bits"] == 7.0
    assert s["unobservable_share"] == pytest.approx(0.7)
    assert s["decrease"] == pytest.approx(1 - 10 / 28)
    assert s["decrease_observable"] == pytest.approx(1 - 3 / 14)
    per_voxel = entropy_split(h, obs, np.array([7.0, 5.0, 7.0, 7.0]))
    assert per_voxel["decrease_observable"] == pytest.approx(1 - 3 / 12)


def test_path_length():
    traj = [[0.0, 0.0, 0.0], [1.0, 3.0, 4.0], [2.0, 3.0, 4.0], [3.0, 0.0, 0.0]]
    assert path_length(traj) == pytest.approx(10.0)
    assert path_length(traj[:1]) == 0.0
    assert path_length([]) == 0.0
