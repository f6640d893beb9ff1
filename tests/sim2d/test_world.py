"""The pymunk world: robots stop at walls, respect their limits and do not overlap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim2d.world import SUBSTEP, World
from swarm.formats.floor_plan import FloorPlan, rectangle, wall_segment

#: The most a disc can overlap an obstacle: one physics sub-step of travel, plus the slop.
OVERLAP = 0.5 * SUBSTEP + 1e-3


def one_wall(thickness: float = 0.1) -> FloorPlan:
    """A wall along x = 2 (faces at 2 -/+ thickness / 2), 10 m long."""
    return FloorPlan([wall_segment((2.0, -5.0), (2.0, 5.0), thickness)], [2.0], (-5, -5), (5, 5))


@pytest.mark.parametrize("thickness", [0.1, 0.02])
@pytest.mark.parametrize("heading", [0.0, 0.5])
def test_robot_driven_at_a_wall_never_passes_it(thickness, heading):
    world = World(one_wall(thickness), radius=0.18, max_speed=0.5)
    world.add_robot("r1", 0.0, 0.0, heading)
    world.command("r1", 10.0, 0.0)  # clipped to 0.5 m/s
    face = 2.0 - thickness / 2
    xs = []
    for _ in range(150):  # 15 s: far enough to cross the wall several times over
        world.step(0.1)
        xs.append(world.pose("r1")[0])
    assert max(xs) <= face - 0.18 + OVERLAP  # never through, barely into
    assert xs[-1] == pytest.approx(face - 0.18, abs=1.5e-3)  # it stops at the wall
    assert world.pose("r1")[2] == pytest.approx(heading)  # contacts do not turn it


def test_speed_and_turn_rate_limits():
    world = World(FloorPlan(np.zeros((0, 4, 2)), [], (-9, -9), (9, 9)), max_speed=0.5, max_turn_rate=1.5)
    world.add_robot("r1", 0.0, 0.0, 0.0)
    world.command("r1", 2.0, 0.0)
    world.step(2.0)
    # A command acts from the next physics sub-step on.
    assert world.pose("r1")[:2] == pytest.approx((0.5 * (2.0 - SUBSTEP), 0.0), abs=1e-9)
    world.command("r1", 0.0, -5.0)
    world.step(1.0)
    assert world.pose("r1")[2] == pytest.approx(-1.5 * (1.0 - SUBSTEP))
    # Driving an arc: v / omega = radius of the circle.
    world = World(FloorPlan(np.zeros((0, 4, 2)), [], (-9, -9), (9, 9)))
    world.add_robot("r1", 0.0, 0.0, 0.0)
    world.command("r1", 0.5, 0.5)
    world.step(2 * math.pi + SUBSTEP)  # half a circle of radius 1 at 0.5 rad/s
    x, y, yaw = world.pose("r1")
    assert (x, y) == pytest.approx((0.0, 2.0), abs=0.01)
    assert abs(yaw) == pytest.approx(math.pi, abs=0.01)
    assert world.robots["r1"].distance == pytest.approx(math.pi, rel=1e-3)


def test_robots_collide_with_each_other_and_boxes():
    box = rectangle((0.0, 2.0), (1.0, 1.0))
    world = World(FloorPlan([box], [0.5], (-9, -9), (9, 9)), radius=0.18)
    world.add_robot("a", -2.0, 0.0, 0.0)
    world.add_robot("b", 2.0, 0.0, math.pi)
    world.add_robot("c", 0.0, 0.0, math.pi / 2)
    for rid in ("a", "b", "c"):
        world.command(rid, 0.5, 0.0)
    for _ in range(100):
        world.step(0.1)
        p = np.array([world.pose(r)[:2] for r in ("a", "b", "c")])
        gaps = np.linalg.norm(p[:, None] - p[None], axis=-1)[np.triu_indices(3, 1)]
        assert gaps.min() >= 2 * 0.18 - 2 * OVERLAP
    assert world.pose("c")[1] == pytest.approx(1.5 - 0.18, abs=1.5e-3)  # stopped by the box
