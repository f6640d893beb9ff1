"""Navigation: traversability from a coverage map, grid planning, path following."""

from __future__ import annotations

import heapq
import math

import numpy as np
import pytest
from scipy import ndimage

from swarm.map.coverage_map import CoverageMap
from swarm.map.grid import Grid
from swarm.navigation.path_follower import FollowerLimits, PathFollower, needs_replan
from swarm.navigation.planner import GridPlanner, nearest_free_cell, path_cost, plan_path, reachable_mask
from swarm.navigation.traversability import TraversabilityGrid, build_traversability, inflate

RES = 0.1


def random_world(seed: int, shape=(40, 60), radius: float = 0.12) -> TraversabilityGrid:
    """Random blobs of occupied and unknown cells, inflated by ``radius``."""
    rng = np.random.default_rng(seed)
    occupied = ndimage.binary_dilation(rng.random(shape) < 0.03, iterations=1)
    unknown = ndimage.binary_dilation(rng.random(shape) < 0.01, iterations=1) & ~occupied
    return TraversabilityGrid.from_blocked(occupied | unknown, (-1.0, 2.0), RES, radius, unknown=unknown)


def reference_costs(free: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """Independent Dijkstra (heapq) with the same moves: 8 neighbours, no corner cutting."""
    dist = np.full(free.shape, np.inf)
    dist[start] = 0.0
    heap = [(0.0, start)]
    while heap:
        d, (i, j) = heapq.heappop(heap)
        if d > dist[i, j]:
            continue
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                a, b = i + di, j + dj
                if (di, dj) == (0, 0) or not (0 <= a < free.shape[0] and 0 <= b < free.shape[1]):
                    continue
                if not free[a, b] or (di and dj and not (free[i + di, j] and free[i, j + dj])):
                    continue
                nd = d + math.hypot(di, dj)
                if nd < dist[a, b] - 1e-12:
                    dist[a, b] = nd
                    heapq.heappush(heap, (nd, (a, b)))
    return dist


def assert_polyline_free(trav: TraversabilityGrid, points: np.ndarray) -> None:
    """Every point of every segment (sampled at 1/50 cell) lies in a navigable cell."""
    for a, b in zip(points[:-1], points[1:], strict=True):
        n = max(int(np.linalg.norm(b - a) / (RES / 50)), 1)
        samples = a + np.linspace(0, 1, n + 1)[:, None] * (b - a)
        cells = np.floor((samples - np.asarray(trav.origin)) / RES).astype(int)
        inside = np.all((cells >= 0) & (cells < trav.shape), axis=1)
        assert inside.all()
        assert trav.free[cells[:, 0], cells[:, 1]].all(), "segment crosses a blocked cell"


# -- planner ------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_planner_never_crosses_blocked_cells_and_finds_existing_paths(seed: int) -> None:
    trav = random_world(seed)
    planner = GridPlanner(trav)
    rng = np.random.default_rng(100 + seed)
    free_cells = np.argwhere(trav.free)
    labels, _ = ndimage.label(trav.free, structure=ndimage.generate_binary_structure(2, 1))
    found = missing = 0
    for _ in range(25):
        s, g = (tuple(int(c) for c in free_cells[k]) for k in rng.integers(len(free_cells), size=2))
        cells = planner.plan_cells(s, g)
        if labels[s] != labels[g]:
            assert cells is None
            missing += 1
            continue
        assert cells is not None
        found += 1
        assert tuple(cells[0]) == s and tuple(cells[-1]) == g
        assert trav.free[cells[:, 0], cells[:, 1]].all()
        assert not (trav.occupied | trav.unknown)[cells[:, 0], cells[:, 1]].any()
        steps = np.diff(cells, axis=0)
        assert np.all(np.abs(steps) <= 1) and np.all(np.abs(steps).sum(axis=1) >= 1)
        for (i, j), (di, dj) in zip(cells[:-1], steps, strict=True):
            if di and dj:  # no corner cutting
                assert trav.free[i + di, j] and trav.free[i, j + dj]
        # World waypoints: start at the start position, end at the goal cell, segments clear.
        start_xy = trav.centre(s) + rng.uniform(-0.4, 0.4, 2) * RES
        waypoints = planner.plan(start_xy, trav.centre(g))
        assert waypoints is not None
        np.testing.assert_allclose(waypoints[0], start_xy)
        np.testing.assert_allclose(waypoints[-1], trav.centre(g))
        assert_polyline_free(trav, waypoints)
        assert path_cost(waypoints) <= path_cost(trav.centre(cells)) + RES
    assert found and missing  # both outcomes were exercised


@pytest.mark.parametrize("seed", range(3))
def test_planner_costs_are_optimal_and_reachability_matches_labels(seed: int) -> None:
    trav = random_world(seed, shape=(25, 30))
    free_cells = np.argwhere(trav.free)
    start = tuple(int(c) for c in free_cells[len(free_cells) // 2])
    costs = GridPlanner(trav).cost_map(start)
    ref = reference_costs(trav.free, start) * RES
    np.testing.assert_allclose(costs, ref, rtol=1e-9)
    labels, _ = ndimage.label(trav.free, structure=ndimage.generate_binary_structure(2, 1))
    reach = reachable_mask(trav, start)
    np.testing.assert_array_equal(reach, labels == labels[start])
    np.testing.assert_array_equal(reach, np.isfinite(ref))
    goal = tuple(int(c) for c in np.argwhere(reach)[-1])
    cells = GridPlanner(trav).plan_cells(start, goal)
    assert path_cost(cells) * RES == pytest.approx(costs[goal])


def test_planner_edge_cases() -> None:
    free = np.ones((5, 5), bool)
    free[2, :] = False
    trav = TraversabilityGrid.from_blocked(~free, (0.0, 0.0), 1.0, 0.0)
    planner = GridPlanner(trav)
    assert planner.plan_cells((0, 0), (4, 4)) is None  # wall across
    assert planner.plan_cells((2, 2), (0, 0)) is None  # start blocked
    assert planner.plan_cells((0, 0), (9, 9)) is None  # goal outside
    assert planner.plan_cells((0, 0), (0, 0)).tolist() == [[0, 0]]
    assert plan_path(trav, (0.5, 0.5), (4.5, 4.5)) is None
    assert not reachable_mask(trav, (2, 2)).any()
    assert nearest_free_cell(trav, (2, 2)) in {(1, 2), (3, 2)}
    # A diagonal gap between two blocked cells is not passable (no corner cutting).
    free = np.ones((2, 2), bool)
    free[0, 1] = free[1, 0] = False
    assert GridPlanner(free).plan_cells((0, 0), (1, 1)) is None
    assert path_cost(np.array([[0, 0], [3, 4]])) == 5.0


# -- traversability ------------------------------------------------------------------------------


def coverage_world() -> tuple[CoverageMap, dict]:
    """A 3 x 2 x 0.8 m map, all known free, with a few special columns."""
    grid = Grid((0.0, 0.0, 0.0), RES, (30, 20, 8))
    cmap = CoverageMap(grid)
    nx, ny, nz = grid.shape
    lam = cmap.lam.reshape(nx, ny, nz)
    eta = cmap.eta.reshape(nx, ny, nz)

    def put(i, j, k, mu, sigma=0.05):
        lam[i, j, k] = 1 / sigma**2
        eta[i, j, k] = mu / sigma**2

    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                put(i, j, k, 0.0)
    cols = {"occupied": (10, 10), "unknown": (20, 5), "above": (5, 15), "floor": (25, 15), "grey": (15, 3)}
    put(*cols["occupied"], 3, 1.0)  # a box at z 0.3-0.4
    lam[cols["unknown"][0], cols["unknown"][1], 2] = CoverageMap(grid).lam[0]  # prior: never seen
    eta[cols["unknown"][0], cols["unknown"][1], 2] = CoverageMap(grid).eta[0]
    put(*cols["above"], 6, 1.0)  # a table top at z 0.6-0.7, above the robot
    put(*cols["floor"], 0, 1.0)  # the floor layer, below the band
    put(*cols["grey"], 4, 0.3)  # E[C] about 0.3: not free
    return cmap, cols


def test_traversability_band_unknown_and_occupied() -> None:
    cmap, cols = coverage_world()
    trav = build_traversability(cmap, floor_clearance=0.1, robot_height=0.5, robot_radius=0.0)
    assert trav.shape == (30, 20)
    assert trav.occupied[cols["occupied"]] and not trav.unknown[cols["occupied"]]
    assert trav.unknown[cols["unknown"]] and not trav.free[cols["unknown"]]
    assert trav.occupied[cols["grey"]]
    assert trav.free[cols["above"]] and trav.free[cols["floor"]]
    assert trav.blocked.sum() == 3
    # Radius 0: only the blocked cells and nothing else (the map edge is 1/2 cell away).
    np.testing.assert_array_equal(trav.free, ~trav.blocked)
    with pytest.raises(ValueError, match="band"):
        build_traversability(cmap, floor_clearance=0.9, robot_height=1.5)


def test_traversability_inflates_by_the_radius() -> None:
    cmap, cols = coverage_world()
    radius = 0.27
    trav = build_traversability(cmap, 0.1, 0.5, robot_radius=radius)
    # Brute force: occupied cells and a ring outside the map are inflated by the radius;
    # unknown cells are blocked themselves but not inflated.
    ring = np.pad(trav.occupied, 1, constant_values=True)
    blocked_xy = trav.centre(np.argwhere(ring) - 1)
    centres = trav.centre(np.argwhere(np.ones(trav.shape, bool)))
    nearest = np.min(np.linalg.norm(centres[:, None, :] - blocked_xy[None], axis=-1), axis=1)
    expected = (nearest > radius + RES / 2) & ~trav.unknown.ravel()
    np.testing.assert_array_equal(trav.free.ravel(), expected)
    assert trav.unknown.any() and not trav.free[trav.unknown].any()
    i, j = cols["occupied"]
    assert not trav.free[i + 3, j] and trav.free[i + 4, j]  # 0.3 m blocked, 0.4 m free for r = 0.27
    assert not trav.free[i + 2, j + 2] and trav.free[i + 3, j + 2]  # 0.283 blocked, 0.36 free


def test_traversability_swept_clears_unknown_only() -> None:
    cmap, cols = coverage_world()
    nx, ny, nz = cmap.grid.shape
    lam0 = CoverageMap(cmap.grid).lam[0]
    lam = cmap.lam.reshape(nx, ny, nz)
    lam[0:8, 0:8, 1:5] = lam0  # the robot's surroundings: never seen
    robot = np.array([[0.35, 0.35]])
    trav = build_traversability(cmap, 0.1, 0.5, robot_radius=0.15, swept=robot)
    cell = tuple(trav.cell_of(robot[0]))
    assert not trav.unknown[cell] and trav.unknown[7, 7]
    disc = np.linalg.norm(trav.centre(np.argwhere(np.ones(trav.shape, bool))) - robot[0], axis=1) <= 0.15
    assert not trav.unknown.ravel()[disc].any()
    before = build_traversability(cmap, 0.1, 0.5, robot_radius=0.15)
    assert before.unknown[cell] and not before.free[cell]
    occupied_cell = cols["occupied"]
    swept_box = build_traversability(cmap, 0.1, 0.5, 0.15, swept=np.array([trav.centre(occupied_cell)]))
    assert swept_box.occupied[occupied_cell]


def test_inflate_single_cell() -> None:
    blocked = np.zeros((11, 11), bool)
    blocked[5, 5] = True
    free = inflate(blocked, 1.0, 1.0)
    # Centre distances: 1 and sqrt(2) are within radius + 1/2 = 1.5; 2 is not.
    assert not free[5, 6] and not free[6, 6] and free[5, 7] and free[7, 7]


def test_needs_replan_when_the_map_blocks_the_path() -> None:
    blocked = np.zeros((30, 30), bool)
    trav = TraversabilityGrid.from_blocked(blocked, (0.0, 0.0), RES, 0.1)
    path = plan_path(trav, (0.55, 0.55), (2.45, 2.45))
    assert path is not None and not needs_replan(path, trav)
    on_path = trav.cell_of((path[0] + path[-1]) / 2)
    blocked_now = blocked.copy()
    blocked_now[tuple(on_path)] = True
    assert needs_replan(path, TraversabilityGrid.from_blocked(blocked_now, (0.0, 0.0), RES, 0.1))
    far = blocked.copy()
    far[2, 27] = True
    assert not needs_replan(path, TraversabilityGrid.from_blocked(far, (0.0, 0.0), RES, 0.1))


# -- follower ------------------------------------------------------------------------------------


def simulate(follower: PathFollower, pose, steps: int = 2000, dt: float = 0.05):
    x, y, yaw = pose
    trace, commands = [], []
    for _ in range(steps):
        cmd = follower.command(x, y, yaw)
        commands.append(cmd)
        if cmd.arrived:
            break
        x += cmd.v * math.cos(yaw) * dt
        y += cmd.v * math.sin(yaw) * dt
        yaw += cmd.omega * dt
        trace.append((x, y))
    return np.array(trace), commands


def corridor_world() -> TraversabilityGrid:
    """An L-shaped corridor 0.8 m wide in a 4 x 4 m room."""
    blocked = np.ones((40, 40), bool)
    blocked[2:10, 2:38] = False  # along y at x 0.2-1.0
    blocked[2:38, 30:38] = False  # along x at y 3.0-3.8
    return TraversabilityGrid.from_blocked(blocked, (0.0, 0.0), RES, 0.18)


def test_follower_converges_and_respects_limits() -> None:
    trav = corridor_world()
    start, goal = np.array([0.6, 0.6]), np.array([3.45, 3.45])
    path = plan_path(trav, start, goal)
    assert path is not None
    limits = FollowerLimits(max_speed=0.4, max_turn_rate=1.2)
    follower = PathFollower(limits)
    follower.set_path(path)
    trace, commands = simulate(follower, (start[0], start[1], math.pi))  # facing away from the path
    assert commands[-1].arrived
    assert np.linalg.norm(trace[-1] - goal) <= limits.goal_tolerance + 0.02
    v = np.array([c.v for c in commands])
    w = np.array([c.omega for c in commands])
    assert np.all(np.abs(v) <= limits.max_speed + 1e-12) and np.all(v >= 0)
    assert np.all(np.abs(w) <= limits.max_turn_rate + 1e-12)
    assert commands[0].v == 0.0 and abs(commands[0].omega) > 0  # turns in place first
    assert v.max() > 0.9 * limits.max_speed  # and then drives at speed on the straight
    # The robot's centre stays in the raw free space of the corridor (no wall contact).
    cells = trav.cell_of(trace)
    assert not trav.blocked[cells[:, 0], cells[:, 1]].any()
    # Time is reasonable: path length / speed plus turning, well under the step budget.
    assert len(commands) * 0.05 < 3 * path_cost(path) / limits.max_speed + 10


def test_follower_arrival_and_empty_path() -> None:
    follower = PathFollower()
    assert follower.command(0, 0, 0).arrived
    follower.set_path(np.array([[1.0, 0.0]]))
    cmd = follower.command(0.0, 0.0, 0.0)
    assert not cmd.arrived and cmd.v > 0 and cmd.omega == pytest.approx(0.0)
    assert follower.command(0.97, 0.0, 0.0).arrived
    with pytest.raises(ValueError):
        FollowerLimits(max_speed=0)
