"""Exact distance to a floor plan's surface (swarm.mission.plan_distance) and the surface
accuracy built on it (swarm.mission.surface_quality.plan_accuracy_completeness)."""

from __future__ import annotations

import numpy as np
import pytest

from sim2d.ground_truth import coverage
from swarm.formats.floor_plan import FloorPlan, rectangle
from swarm.map.grid import Grid
from swarm.mission import surface_quality as sq
from swarm.mission.plan_distance import surface_distance


def _plan(quads, heights, lo=(0, 0), hi=(4, 3)) -> FloorPlan:
    return FloorPlan(
        quads=np.array(quads), heights=np.array(heights, float), lo=np.array(lo), hi=np.array(hi)
    )


def _mixed_plan() -> FloorPlan:
    """Two touching boxes (a shared side inside the solid), a taller box overlapping one of
    them, and a rotated box."""
    return _plan(
        [
            rectangle(np.array([1.0, 1.0]), np.array([1.0, 1.0])),
            rectangle(np.array([2.0, 1.0]), np.array([1.0, 1.0])),
            rectangle(np.array([2.3, 1.2]), np.array([0.4, 0.4])),
            rectangle(np.array([3.0, 2.3]), np.array([0.6, 0.3]), yaw=0.6),
        ],
        [0.5, 0.5, 0.9, 0.7],
    )


def test_exact_distance_agrees_with_a_dense_sampling_of_the_surface():
    # Sampled every 1 cm, the surface is never farther from a point than the exact distance
    # plus the sampling's gap, and never nearer than the exact distance.
    plan = _mixed_plan()
    step = 0.01
    samples, _ = sq.plan_surface_points(plan, np.array([0, 0, 0.0]), np.array([4, 3, 1.2]), step)
    rng = np.random.default_rng(3)
    pts = rng.uniform([0.3, 0.3, 0.0], [3.7, 2.7, 1.1], size=(3000, 3))
    exact = surface_distance(plan, pts, cap=5.0)
    from scipy.spatial import cKDTree

    sampled = np.minimum(cKDTree(samples).query(pts)[0], pts[:, 2])  # the floor z = 0 counts too
    assert np.all(exact <= sampled + 1e-9)
    assert np.all(sampled <= exact + step)
    inside = pts[:, 2] < plan.height_at(pts[:, :2])
    assert 200 < np.count_nonzero(inside) < 2900  # both kinds of point are tested
    # the shared side of the touching boxes is not surface: the middle of their joint is
    # 0.5 m from the boxes' outer sides and 0.2 m below their top
    assert surface_distance(plan, np.array([[1.5, 1.0, 0.3]]))[0] == pytest.approx(0.2)
    assert surface_distance(plan, np.array([[1.5, 1.0, 0.0]]))[0] == pytest.approx(0.0)
    # far from everything: the floor, or the cap
    assert surface_distance(plan, np.array([[0.0, 2.9, 0.3]]), cap=1.0)[0] == pytest.approx(0.3)
    assert surface_distance(plan, np.array([[0.0, 2.9, 3.0]]), cap=1.0)[0] == 1.0
    with pytest.raises(ValueError, match="cap"):
        surface_distance(plan, pts, cap=0.0)


def _thick_walls():
    """0.35 m walls 2 m high whose sides lie on the 0.1 m grid's edges and half edges (as a
    ROS map's 0.05 m cells do), so that voxel centres lie 0.05, 0.10 and 0.15 m inside."""
    plan = _plan(
        [
            rectangle(np.array([1.195, 1.5]), np.array([0.35, 2.0])),  # x 1.02 - 1.37
            rectangle(np.array([2.5, 0.745]), np.array([1.6, 0.35])),  # y 0.57 - 0.92
            rectangle(np.array([2.5, 2.2]), np.array([0.35, 0.35])),  # a pillar
        ],
        [2.0, 2.0, 2.0],
    )
    grid = Grid.from_bounds(np.array([0.02, 0.02, 0.0]), np.array([4.02, 3.02, 2.2]), 0.1)
    return plan, grid


def test_the_true_map_is_accurate_and_complete_and_a_shifted_one_is_not():
    plan, grid = _thick_walls()
    truth = coverage(plan, grid).ravel() > 0.5
    centres = grid.centres().reshape(-1, 3)[truth]
    points, _ = sq.plan_surface_points(plan, grid.lo, grid.hi, 0.5 * grid.voxel)
    tol = sq.TOLERANCE_EDGES * grid.voxel
    out = sq.plan_accuracy_completeness(plan, centres, points, tol)
    assert out["accuracy"] == 1.0
    assert out["completeness"] == 1.0
    # measured against the sampled points, the centres 1.5 edges deep would fail
    sampled = sq.surface_accuracy_completeness(centres, points, tol, floor_z=0.0)
    assert sampled["accuracy"] < 0.95
    # the map moved by 3 voxels along x and y is neither
    shifted = sq.plan_accuracy_completeness(plan, centres + [0.3, 0.3, 0.0], points, tol)
    assert shifted["accuracy"] < 0.7 and shifted["completeness"] < 0.7
