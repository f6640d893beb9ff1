"""Ground-truth coverage: the fraction of each voxel inside obstacles."""

from __future__ import annotations

import numpy as np
import pytest

from sim2d.ground_truth import coverage
from swarm.config import load_mission
from swarm.formats.floor_plan import FloorPlan, load_floor_plan, rectangle
from swarm.map.grid import Grid
from tests.support.paths import CONFIGS


def test_voxel_half_inside_a_wall():
    # A wall from x = 1.05 to 1.5: voxel i = 10 spans [1.0, 1.1], so it is half inside.
    wall = rectangle((1.275, 0.5), (0.45, 3.0))
    plan = FloorPlan([wall], [2.0], (0, 0), (2, 1))
    grid = Grid((0.0, 0.0, 0.0), 0.1, (20, 10, 10))
    cov = coverage(plan, grid)
    assert cov.shape == grid.shape and cov.dtype == np.float32
    assert cov[10, 5, 5] == pytest.approx(0.5, abs=0.05)
    assert np.all(cov[11:15] == 1.0)
    assert np.all(cov[:10] == 0.0) and np.all(cov[15:] == 0.0)


def test_coverage_is_exact_in_height_and_ground_is_solid():
    box = rectangle((0.5, 0.5), (0.6, 0.6))  # covers voxels 2-7 in x and y fully
    plan = FloorPlan([box], [0.25], (0, 0), (1, 1))
    grid = Grid((0.0, 0.0, -0.1), 0.1, (10, 10, 5))  # z from -0.1 to 0.4
    cov = coverage(plan, grid)
    np.testing.assert_allclose(cov[4, 4], [1.0, 1.0, 1.0, 0.5, 0.0])
    np.testing.assert_allclose(cov[0, 0], [1.0, 0.0, 0.0, 0.0, 0.0])  # only the ground
    assert coverage(plan, grid, ground_is_solid=False)[0, 0, 0] == 0.0


def test_oblique_edge_fraction_by_supersampling():
    # A box turned 45 degrees: voxels on its edge are partly covered; total volume is right.
    plan = FloorPlan([rectangle((1.0, 1.0), (1.0, 1.0), np.pi / 4)], [1.0], (0, 0), (2, 2))
    grid = Grid((0.0, 0.0, 0.0), 0.1, (20, 20, 10))
    cov = coverage(plan, grid, samples=8)
    assert cov.sum() * 0.1**3 == pytest.approx(1.0, rel=0.01)
    assert np.any((cov > 0.2) & (cov < 0.8))


def test_lab_furniture_volume():
    mission = load_mission(CONFIGS / "lab.yaml")
    plan = load_floor_plan(CONFIGS / "plans" / "lab.yaml")
    cov = coverage(plan, mission.workspace.grid())
    boxes = [q for q, kind in zip(plan.quads, plan.kinds, strict=True) if kind == "box"]
    heights = plan.heights[[k == "box" for k in plan.kinds]]
    areas = [np.prod(np.linalg.norm(q[1:3] - q[:2], axis=1)) for q in boxes]  # rectangles
    # The walls are the workspace's outermost 0.1 m layer (a 4 x 2 m ring around a
    # 3.8 x 1.8 m room) up to the workspace top at 2 m; the furniture stands inside.
    walls = (4.0 * 2.0 - 3.8 * 1.8) * 2.0
    assert cov.sum() * 0.1**3 == pytest.approx(walls + np.dot(areas, heights), rel=0.02)
