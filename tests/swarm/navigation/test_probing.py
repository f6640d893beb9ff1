"""Probes into unknown floor (swarm.navigation.probing): a room behind a door whose floor is unknown."""

from __future__ import annotations

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.grid import Grid
from swarm.navigation.exploration import SearchContext, SearchOptions, choose_target
from swarm.navigation.planner import GridPlanner
from swarm.navigation.probing import SURE_COVERAGE, open_swept, optimistic_traversability
from swarm.navigation.traversability import build_traversability

GRID = Grid((0.0, 0.0, 0.0), 0.1, (40, 40, 10))  # 4 m x 4 m x 1 m
WALL_J = 15  # the wall row, y 1.5-1.6 m; the corridor below it, the room above
DOOR_I = slice(16, 24)  # the door, x 1.6-2.4 m (0.8 m wide)
ROBOT_HEIGHT, RADIUS, CAMERA_Z = 0.5, 0.18, 0.4
START = (1.0, 0.7, 0.0)


def _set(cmap: CoverageMap, where: tuple, mean: float) -> None:
    """Make the voxels ``where`` (an index of the (nx, ny, nz) grid) known with this mean."""
    lam = cmap.lam.reshape(GRID.shape)
    eta = cmap.eta.reshape(GRID.shape)
    lam[where] = 1.0 / 0.02**2
    eta[where] = mean * lam[where]


def _corridor_and_room(door: float | None) -> CoverageMap:
    """A known free corridor (y < 1.5 m), a known wall, and a room beyond it whose floor no view
    reached (unknown). ``door``: the mean of the door's top band voxel (z 0.4-0.5 m), the
    smeared stereo return at a door's jambs; None for no door (the wall goes on)."""
    cmap = CoverageMap(GRID)
    _set(cmap, (slice(None), slice(0, WALL_J), slice(None)), 0.0)
    _set(cmap, (slice(None), WALL_J, slice(None)), 1.0)
    if door is not None:
        _set(cmap, (DOOR_I, WALL_J, slice(None)), 0.0)
        _set(cmap, (DOOR_I, WALL_J, 4), door)
    return cmap


def _choose(cmap: CoverageMap, optimistic: bool):
    trav = build_traversability(cmap, robot_height=ROBOT_HEIGHT, robot_radius=RADIUS)
    opt = optimistic_traversability(cmap, trav, ROBOT_HEIGHT) if optimistic else None
    cost = GridPlanner(trav).cost_map(tuple(int(c) for c in trav.cell_of(np.array(START[:2]))))
    entropy = np.zeros(GRID.size)  # no eq. 35 gradient anywhere: the fallbacks decide
    ctx = SearchContext.build(cmap, entropy, START, CAMERA_Z, trav, cost)
    target = choose_target(
        "entropy", ctx, SearchOptions(radius=1.5), np.random.default_rng(0), optimistic=opt
    )
    return target, trav, opt


def test_a_room_behind_a_door_with_a_smeared_threshold_and_unknown_floor_is_probed():
    cmap = _corridor_and_room(door=0.3)
    trav = build_traversability(cmap, robot_height=ROBOT_HEIGHT, robot_radius=RADIUS)
    # the fault: the threshold is ambiguous (0.2 <= E[C] < SURE_COVERAGE), the room unknown, so
    # known free space ends at the wall and the planner has no way in
    door_cov = float(expected_coverage(np.array([0.3]), np.array([0.02]))[0])
    assert 0.2 <= door_cov < SURE_COVERAGE
    inside = np.array([2.0, 2.5])
    assert GridPlanner(trav).plan(np.array(START[:2]), inside) is None
    without, _, _ = _choose(cmap, optimistic=False)
    assert without is None or without.kind != "probe"

    target, trav, opt = _choose(cmap, optimistic=True)
    assert target is not None and target.kind == "probe"
    assert 1.6 < target.xy[1] < 4.0 and 1.6 <= target.xy[0] <= 2.4  # in the room, past the door
    assert target.gaze_yaw > 0  # looking into the room (north)
    # the room's unknown floor (m^2), but for the band along its walls the robot's disc keeps off
    assert 0.9 * (4.0 - 2 * RADIUS) * (2.4 - 2 * RADIUS) <= target.utility <= 4.0 * 2.4
    path = GridPlanner(opt).plan(np.array(START[:2]), target.xy)
    assert path is not None
    # the path goes through the door and keeps the robot's disc clear of the surely occupied wall
    for p in path:
        assert opt.is_free(opt.cell_of(p))
    along = np.linspace(path[:-1], path[1:], 20).reshape(-1, 2)
    crossing = along[(along[:, 1] > 1.45) & (along[:, 1] < 1.65)]  # in the wall's row
    assert crossing.size
    assert np.all((crossing[:, 0] > 1.6 + RADIUS - 0.06) & (crossing[:, 0] < 2.4 - RADIUS + 0.06))


def test_no_probe_through_a_wall_or_a_surely_occupied_door():
    for door in (None, 0.9):  # no door, or a door blocked by something seen well
        target, _, opt = _choose(_corridor_and_room(door), optimistic=True)
        assert target is None or target.kind != "probe"
        assert GridPlanner(opt).plan(np.array(START[:2]), np.array([2.0, 2.5])) is None


def test_the_way_back_through_a_swept_door_stays_open():
    cmap = _corridor_and_room(door=0.3)
    _set(cmap, (slice(None), slice(WALL_J + 1, None), slice(None)), 0.0)  # the room now seen free
    trav = build_traversability(cmap, robot_height=ROBOT_HEIGHT, robot_radius=RADIUS)
    opt = optimistic_traversability(cmap, trav, ROBOT_HEIGHT)
    back = (np.array([2.0, 2.5]), np.array(START[:2]))
    assert GridPlanner(trav).plan(*back) is None  # the smeared threshold shuts the robot in
    swept = np.stack([np.full(30, 2.0), np.linspace(0.8, 2.5, 30)], axis=1)  # it drove through
    opened = open_swept(trav, opt, swept)
    assert GridPlanner(opened).plan(*back) is not None
    assert not (opened.free & ~opt.free).any()  # never where something is surely occupied
