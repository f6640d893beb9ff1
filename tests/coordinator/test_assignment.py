"""Burgard-style coordination (coordinator.assignment) and the ranked entropy targets it scores."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from coordinator.assignment import (
    CoordinationParams,
    ObservedColumns,
    assign_team,
    best_target,
    discounted_utilities,
    normalised_utilities,
    teammates_share,
    visibility_discount,
)
from coordinator.assignment_book import AssignmentBook
from swarm.map.grid import Grid
from swarm.navigation.exploration import SearchContext, SearchOptions, choose_target, rank_entropy_targets
from swarm.navigation.planner import GridPlanner
from swarm.navigation.standing_points import ViewGeometry
from swarm.navigation.traversability import build_traversability
from tests.support.exploration_scene import SENSOR_Z, Scene

R = 3.0  # footprint radius of the hand-built cases


# ---------------------------------------------------------------------------------------
# The rule
# ---------------------------------------------------------------------------------------
def test_visibility_discount_and_normalisation():
    assert visibility_discount([0.0, 1.5, 3.0, 7.0], R) == pytest.approx([0.0, 0.5, 1.0, 1.0])
    assert normalised_utilities([2.0, 4.0, np.nan]) == pytest.approx([0.5, 1.0, 0.0])
    u = discounted_utilities([1.0, 1.0, 1.0], [[0, 0], [1.5, 0], [9, 0]], [[0, 0], [3, 0]], R)
    assert u == pytest.approx([0.0, 0.5 * 0.5, 1.0])
    with pytest.raises(ValueError):
        visibility_discount(1.0, 0.0)
    with pytest.raises(ValueError):
        CoordinationParams(beta=-1.0)
    with pytest.raises(ValueError):
        best_target([1.0, 2.0], [[0, 0]], [0.0, 0.0])


def test_burgard_discount_orders_the_assignments():
    # Three targets on a line, all within one footprint of A: the spacing rule cannot
    # decide, the discount does. After A: B keeps 0.9 * 1/3 = 0.3, C keeps 0.8 * 2.5/3 = 0.67.
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [2.5, 0.0]])
    scores = np.array([10.0, 9.0, 8.0])  # eq. 35, normalised to 1, 0.9, 0.8
    free = np.zeros((2, 3))
    params = CoordinationParams(beta=0.0, footprint_radius=R)
    assert assign_team(scores, pos, free, params=params) == [(0, 0), (1, 2)]
    # without the discount (a tiny footprint) the second robot would take B
    tiny = CoordinationParams(beta=0.0, footprint_radius=1e-3)
    assert assign_team(scores, pos, free, params=tiny) == [(0, 0), (1, 1)]
    # path costs pick the pair: robot 1 is next to A and robot 0 far from it, so robot 1
    # gets A first; robot 0 then weighs C (0.67 - 0.1 * 1) above B (0.3 - 0.1 * 2)
    costs = np.array([[6.0, 2.0, 1.0], [0.0, 1.0, 2.5]])
    p = CoordinationParams(beta=0.1, footprint_radius=R)
    assert assign_team(scores, pos, costs, params=p) == [(1, 0), (0, 2)]
    # one request with A held by another robot gives the same answer as the batch
    assert best_target(scores, pos, costs[0], held=[pos[0]], params=p) == 2
    # a target held already is never given again, even when it is the only one
    assert best_target(scores[:1], pos[:1], [0.0], held=[pos[0]], params=p) is None


def test_spacing_beats_path_cost_while_anything_outside_the_footprints_is_left():
    # B is next to held A and cheap; C is 5 m away, costly and barely informative.
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 0.0]])
    scores = np.array([1.0, 1.0, 0.01])
    costs = np.array([0.5, 0.0, 50.0])
    p = CoordinationParams(beta=0.1, footprint_radius=R)
    assert best_target(scores, pos, costs, held=[pos[0]], params=p) == 2
    # unreachable targets are never given
    assert best_target(scores, pos, [0.5, 0.0, np.inf], held=[pos[0]], params=p) == 1
    assert best_target(scores, pos, [np.inf] * 3, params=p) is None


def _check_order(pos, costs, pairs, held, radius):
    """Replays assignments in order: each target new and, whenever the robot could reach an
    untaken target outside every earlier footprint, outside them too."""
    chosen = [np.asarray(h, dtype=np.float64) for h in held]
    given: set[int] = set()
    for robot, t in pairs:
        assert t not in given, "a target was given twice"
        given.add(t)
        if chosen:
            d = np.linalg.norm(pos[:, None, :] - np.asarray(chosen)[None, :, :], axis=-1).min(axis=1)
        else:
            d = np.full(len(pos), np.inf)
        spaced = (d >= radius) & np.isfinite(costs[robot])
        spaced[list(given - {t})] = False
        if spaced.any():
            assert d[t] >= radius, f"target {t} is {d[t]:.2f} m from another robot's target"
        assert d[t] > 0, "a target at another robot's target"
        chosen.append(pos[t])


@pytest.mark.parametrize("seed", range(3))
def test_random_teams_never_share_or_crowd_targets(seed):
    rng = np.random.default_rng(seed)
    for _ in range(150):
        k = int(rng.integers(1, 40))
        n_robots = int(rng.integers(2, 6))
        pos = rng.uniform(0, 20, (k, 2))
        if rng.random() < 0.3:  # duplicated targets
            pos[rng.integers(k)] = pos[0]
        robots = rng.uniform(0, 20, (n_robots, 2))
        costs = np.linalg.norm(robots[:, None] - pos[None], axis=-1) * rng.uniform(1.0, 1.6, (n_robots, k))
        costs[rng.random(costs.shape) < 0.15] = np.inf
        held = rng.uniform(0, 20, (int(rng.integers(0, 3)), 2))
        params = CoordinationParams(
            beta=float(rng.uniform(0, 0.3)), footprint_radius=float(rng.uniform(1, 6))
        )
        scores = rng.uniform(20, 80, k)
        pairs = assign_team(scores, pos, costs, held, params)
        assert len({r for r, _ in pairs}) == len(pairs)
        _check_order(pos, costs, pairs, held, params.footprint_radius)
        # a robot left out could reach nothing useful that was left
        taken = [pos[t] for _, t in pairs]
        u = discounted_utilities(normalised_utilities(scores), pos, [*held, *taken], params.footprint_radius)
        for r in set(range(n_robots)) - {r for r, _ in pairs}:
            assert not np.any(np.isfinite(costs[r]) & (u > 0))

        # the same team asking one by one, each keeping what it got (the coordinator's way)
        got: list[tuple[int, int]] = []
        for r in range(n_robots):
            others = [*held, *(pos[t] for _, t in got)]
            t = best_target(scores, pos, costs[r], others, params)
            if t is not None:
                got.append((r, t))
        _check_order(pos, costs, got, held, params.footprint_radius)


# ---------------------------------------------------------------------------------------
# Teammates' ground
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(3))
def test_teammates_share_counts_the_disc_cell_by_cell(seed):
    rng = np.random.default_rng(seed)
    lo, voxel, radius = np.array([-1.0, 2.0]), 0.25, 1.3
    mask = rng.random((23, 17)) < 0.4
    points = np.column_stack([rng.uniform(-2.0, 5.5, 40), rng.uniform(1.0, 7.0, 40)])
    got = teammates_share(points, mask, lo, voxel, radius)
    for p, share in zip(points, got, strict=True):
        # independent: walk every cell of the grid, keep those whose offset from the
        # point's cell is within the radius
        own = np.floor((p - lo) / voxel)
        hits = total = 0
        for i in range(mask.shape[0]):
            for j in range(mask.shape[1]):
                if np.hypot(i - own[0], j - own[1]) * voxel <= radius:
                    total += 1
                    hits += bool(mask[i, j])
        assert share == pytest.approx(hits / total if total else 0.0)
    assert teammates_share(np.zeros((0, 2)), mask, lo, voxel, radius).shape == (0,)
    with pytest.raises(ValueError):
        teammates_share(points, mask.ravel(), lo, voxel, radius)


def test_observed_columns_give_each_cell_to_the_robot_that_brought_it_most_information():
    grid = Grid((0.0, 0.0, 0.0), 0.1, (10, 6, 3))
    cols = ObservedColumns(grid.shape)
    flat = np.ravel_multi_index(([2, 2, 7, 5], [1, 1, 4, 0], [0, 2, 1, 1]), grid.shape)
    cols.add("a", flat[:2], [2.0, 3.0])  # column (2, 1): 5 from a
    cols.add("b", flat[:3], [1.0, 1.0, 4.0])  # column (2, 1): 2 from b; column (7, 4): 4
    cols.add("a", flat[2:], [0.5, 1.0])  # a glances at (7, 4) and sees (5, 0)
    cols.add("b", flat[3:], [np.nan])  # a malformed figure counts as nothing
    cell = {(2, 1): 2 * 6 + 1, (7, 4): 7 * 6 + 4, (5, 0): 5 * 6 + 0}

    def cells(*names):
        out = np.zeros(60, dtype=bool)
        out[[cell[n] for n in names]] = True
        return out.reshape(10, 6)

    # each cell goes to its largest contributor, whatever else glanced at it
    assert np.array_equal(cols.teammates_ground("a"), cells((7, 4)))
    assert np.array_equal(cols.teammates_ground("b"), cells((2, 1), (5, 0)))
    # a robot with no deltas: every observed cell is teammates' ground
    assert np.array_equal(cols.teammates_ground("c"), cells((2, 1), (7, 4), (5, 0)))
    assert cols.robots() == ["a", "b"]
    with pytest.raises(ValueError):
        cols.add("a", flat[:2], [1.0])


@pytest.mark.parametrize("seed", range(4))
def test_teammates_ground_kept_as_deltas_come_equals_the_pass_over_every_robot(seed):
    # the kept best / owner / second-best per cell against the maximum over the others' totals,
    # with ties (integer information), robots arriving late and a robot never heard
    rng = np.random.default_rng(seed)
    shape = (9, 7, 4)
    cols = ObservedColumns(shape)
    robots = ["a", "b", "c", "d"]
    for _ in range(40):
        robot = robots[int(rng.integers(len(robots)))]
        voxels = rng.integers(0, 9 * 7 * 4, int(rng.integers(1, 30)))
        cols.add(robot, voxels, rng.integers(0, 3, len(voxels)).astype(float))
        for asker in [*robots, "nobody"]:
            mine = cols._by_robot.get(asker, np.zeros(63))
            others = np.zeros(63)
            for rid, total in cols._by_robot.items():
                if rid != asker:
                    others = np.maximum(others, total)
            assert np.array_equal(cols.teammates_ground(asker), (others > mine).reshape(9, 7))


@pytest.mark.parametrize("radius", [0.0, 0.3, 1.0, 1.3, 2.2])
def test_teammates_share_near_and_off_the_grid_edges(radius):
    rng = np.random.default_rng(int(radius * 10))
    lo, voxel = np.array([0.0, 0.0]), 0.25
    mask = rng.random((11, 8)) < 0.5
    points = np.column_stack([rng.uniform(-1.5, 4.5, 60), rng.uniform(-1.5, 3.5, 60)])
    got = teammates_share(points, mask, lo, voxel, radius)
    for p, share in zip(points, got, strict=True):
        own = np.floor((p - lo) / voxel).astype(int)
        hits = total = 0
        for i in range(mask.shape[0]):
            for j in range(mask.shape[1]):
                di, dj = i - own[0], j - own[1]
                if (di * di + dj * dj) * voxel * voxel <= radius * radius:
                    total += 1
                    hits += bool(mask[i, j])
        assert share == (hits / total if total else 0.0)


def test_teammates_ground_lowers_a_target_but_never_hides_it():
    # Two equal targets, equally far: A lies in ground only a teammate has seen.
    pos = np.array([[0.0, 0.0], [10.0, 0.0]])
    scores, costs = np.array([1.0, 1.0]), np.array([2.0, 2.0])
    p = CoordinationParams(beta=0.1, footprint_radius=R, overlap_weight=1.0)
    assert best_target(scores, pos, costs, params=p, teammates=[0.8, 0.0]) == 1
    # a better A still wins once its lowered utility beats B: 1.0 * (1 - 0.8) < 0.15
    assert best_target([1.0, 0.15], pos, costs, params=p, teammates=[0.8, 0.0]) == 0
    # weight 0 is Burgard's rule alone
    burgard = CoordinationParams(beta=0.1, footprint_radius=R, overlap_weight=0.0)
    assert best_target([1.0, 0.9], pos, costs, params=burgard, teammates=[0.8, 0.0]) == 0
    # a target wholly in teammates' ground is still given when it is the only one
    assert best_target(scores[:1], pos[:1], costs[:1], params=p, teammates=[1.0]) == 0
    # the batch rule lowers per robot: robot 0 knows A's ground, robot 1 does not
    shares = np.array([[0.0, 0.0], [0.9, 0.0]])
    free = np.zeros((2, 2))
    assert sorted(assign_team(scores, pos, free, params=p, teammates=shares)) == [(0, 0), (1, 1)]
    with pytest.raises(ValueError):
        best_target(scores, pos, costs, params=p, teammates=[0.5])
    with pytest.raises(ValueError):
        CoordinationParams(overlap_weight=1.5)


# ---------------------------------------------------------------------------------------
# Who holds what
# ---------------------------------------------------------------------------------------
def test_released_and_silent_robots_free_their_targets():
    p = CoordinationParams(beta=0.0, footprint_radius=R, robot_timeout_s=5.0, status_grace_s=1.0)
    book = AssignmentBook(p)
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [9.0, 0.0]])  # A, B (near A), C (far)
    scores = np.array([1.0, 0.9, 0.2])
    costs = np.zeros(3)

    def best(robot: str) -> int | None:
        return best_target(scores, pos, costs, book.held_by_others(robot), p)

    def ask(robot: str, now: float) -> int | None:
        book.note_request(robot, now)
        book.expire(now)
        t = best(robot)
        if t is not None:
            book.hold(robot, pos[t], now)
        return t

    assert ask("r1", 0.0) == 0
    assert ask("r2", 0.1) == 2  # A is held: B is within its footprint, C is not
    assert ask("r1", 0.2) == 0  # asking again releases A, and A is still the best
    # a status that may predate the assignment (no target) changes nothing during the grace
    assert book.note_status("r1", 0.5, (0, 0), "choose", None) == []
    assert ask("r3", 0.6) == 1  # every target is within a footprint: the discount decides
    # after the grace, a status without a target releases; "done" releases at any time
    assert book.note_status("r1", 1.5, (0, 0), "choose", None) == [("r1", "status choose without a target")]
    assert ask("r2", 1.6) == 2
    assert book.note_status("r2", 1.7, (0, 0), "done", None) == [("r2", "status done")]
    assert book.held_by_others("r4").tolist() == [[1.0, 0.0]]
    # a robot that chose for itself holds what its status shows
    assert book.note_status("r5", 2.0, (5, 0), "drive", (9.0, 0.0, 0.0)) == []
    assert ask("r4", 2.1) == 0
    assert best("r6") is None  # A, B and C are all held
    # r3 and r5 fall silent; after the timeout their targets are free again
    assert book.note_status("r4", 7.0, (0, 0), "drive", (0.0, 0.0, 0.0)) == []
    assert book.expire(7.2) == [("r3", "silent for 6.6 s"), ("r5", "silent for 5.2 s")]
    assert book.live() == ["r4"]
    assert book.held_by_others("r6").tolist() == [[0.0, 0.0]]
    assert best("r6") == 2
    assert [t.tolist() for t in book.recent_releases("r2")] == [[9.0, 0.0], [9.0, 0.0]]
    # a silent robot that speaks again is live again
    book.note_status("r3", 7.5, (1, 0), "drive", (1.0, 0.0, 0.0))
    assert book.held_by_others("r6").tolist() == [[1.0, 0.0], [0.0, 0.0]]


# ---------------------------------------------------------------------------------------
# The ranked candidates of one map
# ---------------------------------------------------------------------------------------
def _random_scene(seed: int) -> Scene:
    rng = np.random.default_rng(seed)
    nx, ny = 50, 40
    s = Scene(nx, ny)
    known = ndimage.binary_dilation(rng.random((nx, ny)) < 0.02, iterations=int(rng.integers(3, 9)))
    occ = known & (rng.random((nx, ny)) < 0.05)
    s.set(known & ~occ, 0.0, rng.uniform(0.01, 0.05, (nx, ny)))
    s.set(occ, 1.0, 0.05)
    return s


@pytest.mark.parametrize("seed", range(6))
def test_ranked_targets_start_with_choose_target_and_carry_their_costs(seed):
    scene = _random_scene(seed)
    rng = np.random.default_rng(seed)
    trav = build_traversability(scene.cmap, robot_radius=0.18)
    free = np.argwhere(trav.free)
    assert len(free)
    planner = GridPlanner(trav)
    H = scene.entropy()
    for _ in range(3):
        cell = free[rng.integers(len(free))]
        xy = trav.centre(cell)
        cost = planner.cost_map(tuple(cell))
        pose = (xy[0], xy[1], 0.0)
        ctx = SearchContext.build(scene.cmap, H, pose, SENSOR_Z, trav, cost)
        options = SearchOptions(radius=1.0, view=ViewGeometry(0.3, 1.0))
        ranked = rank_entropy_targets(ctx, options)
        first = choose_target("entropy", ctx, options, np.random.default_rng(0))
        if ranked:
            assert first.kind == "entropy"
            assert first.voxel == ranked[0].voxel and np.allclose(first.xy, ranked[0].xy)
            assert first.utility == ranked[0].utility and first.gaze_yaw == ranked[0].gaze_yaw
        else:
            assert first is None or first.kind == "wander"
        # the whole map in one ring: utilities never increase; spacing and limit respected
        whole = rank_entropy_targets(
            ctx, SearchOptions(radius=100.0), limit=30, min_separation=0.5, max_rejects=100
        )
        assert len(whole) <= 30
        u = [c.utility for c in whole]
        assert u == sorted(u, reverse=True)
        pts = np.array([c.point[:2] for c in whole]).reshape(-1, 2)
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(pts)) * 1e9
        assert np.all(d >= 0.5 - 1e-9)
        for c in whole:
            stand = tuple(trav.cell_of(c.xy))
            assert c.path_cost == (0.0 if stand == tuple(cell) else cost[stand])
            assert np.isfinite(c.path_cost)
            assert 0.3 - 1e-9 <= np.linalg.norm(c.point[:2] - c.xy) <= 1.0 + 1e-9
    with pytest.raises(ValueError):
        rank_entropy_targets(ctx, options, limit=0)
