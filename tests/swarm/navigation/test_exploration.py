"""Exploration targets: the eq. 35 entropy-gradient target, frontier and random baselines."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from swarm.map.entropy import expected_coverage
from swarm.navigation.exploration import (
    ExplorationTarget,
    SearchContext,
    SearchOptions,
    choose_target,
    frontier_cells,
)
from swarm.navigation.planner import GridPlanner
from swarm.navigation.traversability import TraversabilityGrid, inflate
from tests.support.exploration_scene import NZ, SENSOR_Z, E, Scene

K0 = 4


def brute_scores(scene: Scene) -> np.ndarray:
    """Eq. 35 on the slab, written out voxel by voxel: backward differences / e, z dropped."""
    nx, ny, _ = scene.grid.shape
    H = scene.entropy().reshape(scene.grid.shape).astype(np.float64)[:, :, K0]
    idx = np.arange(nx * ny) * NZ + K0
    ec = expected_coverage(scene.cmap.mean(idx), scene.cmap.sigma(idx)).reshape(nx, ny)
    scores = np.zeros((nx, ny))
    for i in range(nx):
        for j in range(ny):
            gx = (H[i, j] - H[i - 1, j]) / E if i > 0 else 0.0
            gy = (H[i, j] - H[i, j - 1]) / E if j > 0 else 0.0
            scores[i, j] = math.hypot(gx, gy) * (1.0 - ec[i, j])
    return scores


def in_radius(scene: Scene, xy, radius: float) -> np.ndarray:
    """Slab columns whose voxel centre lies within ``radius`` of the sensor (eq. 30)."""
    ii, jj = scene.columns()
    w = (ii + 0.5) * E - xy[0], (jj + 0.5) * E - xy[1], (K0 + 0.5) * E - SENSOR_Z
    return w[0] ** 2 + w[1] ** 2 + w[2] ** 2 <= radius**2


def viewable(scene: Scene, cost: np.ndarray, lo: float = 0.3, hi: float = 1.0) -> np.ndarray:
    """Columns with a reachable cell at distance lo..hi (no line-of-sight test: open scenes only)."""
    ii, jj = scene.columns()
    ri, rj = np.nonzero(np.isfinite(cost))
    out = np.zeros(ii.shape, dtype=bool)
    for a, b in zip(ri, rj, strict=True):
        d = np.hypot(ii - a, jj - b) * E
        out |= (d >= lo - 1e-9) & (d <= hi + 1e-9)
    return out


def column_of(target: ExplorationTarget, scene: Scene) -> tuple[int, int]:
    i, j, k = (int(v) for v in scene.grid.unflat(target.voxel))
    assert k == K0
    return i, j


# ---------------------------------------------------------------------------------------
# Entropy gradient (eq. 35)
# ---------------------------------------------------------------------------------------
def test_entropy_target_is_the_eq35_argmax_and_looks_at_the_unknown():
    scene = Scene(40, 30)
    ii, _ = scene.columns()
    rng = np.random.default_rng(3)
    scene.set(ii < 20, 0.0, rng.uniform(0.01, 0.02, ii.shape))  # known free, x < 2 m; unknown beyond
    xy, xi = (1.0, 1.5), 1.5
    trav, cost = scene.plan(xy)
    target = scene.choose("entropy", xy, xi)
    assert target is not None and target.kind == "entropy"

    scores = np.where(in_radius(scene, xy, xi) & viewable(scene, cost), brute_scores(scene), -np.inf)
    best = np.unravel_index(np.argmax(scores), scores.shape)
    assert column_of(target, scene) == best
    assert target.utility == pytest.approx(scores[best], rel=1e-4)
    assert best[0] == 20  # the first unknown column: the frontier
    # gaze towards the unknown side (+x), standing on the explored side within view range
    assert math.cos(target.gaze_yaw) > 0.99
    w = scene.grid.centre(np.array([*best, K0]))[:2]
    assert np.isfinite(cost[tuple(trav.cell_of(target.xy))])
    assert 0.3 - 1e-9 <= np.linalg.norm(w - target.xy) <= 1.0 + 1e-9
    assert target.xy[0] < w[0]

    # excluding the chosen spot moves the target at least 1 m away from it
    other = scene.choose("entropy", xy, xi, exclude=[w])
    assert other is not None and other.kind == "entropy"
    assert np.linalg.norm(scene.grid.centre(np.array([*column_of(other, scene), K0]))[:2] - w) > 1.0


def check_view(scene: Scene, target: ExplorationTarget, cost: np.ndarray, trav) -> np.ndarray:
    """The target voxel is 0.3-1 m ahead of the standing point, within 30 deg of the gaze."""
    w = scene.grid.centre(scene.grid.unflat(target.voxel))[:2]
    gaze = np.array([math.cos(target.gaze_yaw), math.sin(target.gaze_yaw)])
    ahead = w - target.xy
    assert np.isfinite(cost[tuple(trav.cell_of(target.xy))])
    assert 0.3 - 1e-9 <= np.linalg.norm(ahead) <= 1.0 + 1e-9
    assert np.dot(ahead, gaze) >= math.cos(math.radians(30)) * np.linalg.norm(ahead) - 1e-9
    return ahead


def test_the_robot_stands_back_from_the_target_and_faces_it():
    scene = Scene(40, 40)
    ii, jj = scene.columns()
    pocket = (ii >= 18) & (ii <= 21) & (jj >= 18) & (jj <= 21)  # unknown, in open known space
    scene.set(~pocket, 0.0, 0.04)
    xy = (1.0, 1.0)
    trav, cost = scene.plan(xy)
    target = scene.choose("entropy", xy, 3.0)
    ahead = check_view(scene, target, cost, trav)
    assert np.linalg.norm(ahead) == pytest.approx(0.65, abs=0.1)  # open space: the ideal distance
    i, j = column_of(target, scene)
    gaze = np.array([math.cos(target.gaze_yaw), math.sin(target.gaze_yaw)])
    assert pocket[int(i + round(2 * gaze[0])), int(j + round(2 * gaze[1]))]  # the gaze enters the pocket

    # a wall segment where the robot stood, across its view: it must still see its target
    # ahead (here: it picks another voxel of the same score on another side of the pocket)
    assert (i, j) == (18, 22) and np.allclose(target.xy, [1.85, 2.85])
    scene.set((jj >= 27) & (jj <= 28) & (ii >= 13) & (ii <= 23), 1.0, 0.04)
    trav, cost = scene.plan(xy)
    other = scene.choose("entropy", xy, 3.0)
    assert other.kind == "entropy"
    check_view(scene, other, cost, trav)


def test_unreachable_or_unviewable_candidates_are_never_chosen():
    scene = Scene(60, 30)
    ii, jj = scene.columns()
    left, wall, right = ii < 30, ii == 30, ii > 30
    pocket_l = (ii >= 5) & (ii <= 7) & (jj >= 20) & (jj <= 23)
    pocket_r = (ii >= 33) & (ii <= 35) & (jj >= 10) & (jj <= 20)
    scene.set(left & ~pocket_l, 0.0, 0.05)
    scene.set(wall, 1.0, 0.05)
    scene.set(right & ~pocket_r, 0.0, 0.02)  # crisper free space: a steeper gradient behind the wall
    xy, xi = (1.5, 1.0), 3.5
    trav, cost = scene.plan(xy)
    assert not np.isfinite(cost[right]).any()

    scores = brute_scores(scene)
    near = in_radius(scene, xy, xi)
    unfiltered = np.unravel_index(np.argmax(np.where(near, scores, -np.inf)), scores.shape)
    assert unfiltered[0] > 30  # without the reachability test the target would be behind the wall
    # right pocket's left edge is within 1 m of reachable cells, but only through the wall
    assert viewable(scene, cost)[33, 15]

    target = scene.choose("entropy", xy, xi)
    assert target is not None and target.kind == "entropy"
    i, j = column_of(target, scene)
    assert i < 30
    expected = np.where(near & left & viewable(scene, cost), scores, -np.inf)
    assert target.utility == pytest.approx(expected.max(), rel=1e-4)
    assert np.isfinite(cost[tuple(trav.cell_of(target.xy))])


def test_widening_finds_a_far_target_and_a_known_map_has_none():
    scene = Scene(80, 20)
    ii, _ = scene.columns()
    scene.set(ii < 60, 0.0, 0.015)  # uniform known free space up to x = 6 m (2 bits a voxel)
    xy, xi = (1.0, 1.0), 1.0
    target = scene.choose("entropy", xy, xi)
    assert target is not None and target.kind == "entropy"
    i, j = column_of(target, scene)
    assert i == 60
    assert np.hypot((i + 0.5) * E - xy[0], (j + 0.5) * E - xy[1]) > 2 * xi
    # the paper's fixed radius: nothing conclusive, unknown space in sensor range: wander
    wander = scene.choose("entropy", xy, xi, widen=False)
    assert wander is not None and wander.kind == "wander" and wander.voxel is None
    # a high threshold makes even the frontier inconclusive
    assert scene.choose("entropy", xy, xi, min_score=1e4).kind == "wander"

    scene.set(ii >= 60, 0.0, 0.015)  # everything known
    for strategy in ("entropy", "frontier", "random"):
        assert scene.choose(strategy, xy, xi) is None


def test_unknown_space_behind_walls_stops_the_mission():
    scene = Scene(40, 20)
    ii, _ = scene.columns()
    scene.set(ii < 20, 0.0, 0.015)
    scene.set(ii == 20, 1.0, 0.015)  # a wall hides the other room
    scene.set((ii > 20) & (ii < 30), 0.0, 0.015)  # which is half explored
    xy = (1.0, 1.0)
    for strategy in ("entropy", "frontier", "random"):
        assert scene.choose(strategy, xy, 1.0) is None
    assert scene.choose("entropy", (2.5, 1.0), 1.0).kind == "entropy"  # from inside it, it is not


def test_bad_inputs_are_rejected():
    scene = Scene(20, 10)
    ii, _ = scene.columns()
    scene.set(ii < 10, 0.0, 0.04)
    trav, cost = scene.plan((0.5, 0.5))
    rng = np.random.default_rng(0)
    args = (scene.cmap, scene.entropy(), (0.5, 0.5, 0.0))
    ctx = SearchContext.build(*args, SENSOR_Z, trav, cost)
    with pytest.raises(ValueError, match="unknown exploration strategy 'spiral'"):
        choose_target("spiral", ctx, SearchOptions(radius=1.0), rng)
    with pytest.raises(ValueError, match="sensor height"):
        SearchContext.build(*args, 5.0, trav, cost)  # sensor above the map
    with pytest.raises(ValueError, match="planner_cost"):
        SearchContext.build(*args, SENSOR_Z, trav, cost[:-1])
    with pytest.raises(ValueError, match="entropy"):
        SearchContext.build(scene.cmap, scene.entropy()[:-1], (0.5, 0.5, 0.0), SENSOR_Z, trav, cost)
    with pytest.raises(ValueError, match="radius"):
        SearchOptions(radius=0.0)


# ---------------------------------------------------------------------------------------
# Frontier baseline
# ---------------------------------------------------------------------------------------
def blob_world(seed: int, shape=(40, 30), radius: float = 0.0) -> tuple[Scene, TraversabilityGrid]:
    rng = np.random.default_rng(seed)
    occupied = ndimage.binary_dilation(rng.random(shape) < 0.03, iterations=1)
    unknown = ndimage.binary_dilation(rng.random(shape) < 0.01, iterations=1) & ~occupied
    trav = TraversabilityGrid.from_blocked(occupied | unknown, (0.0, 0.0), E, radius, unknown=unknown)
    return Scene(*shape), trav


def choose_on(scene: Scene, trav: TraversabilityGrid, strategy: str, xy, radius=1.0, seed=0, exclude=()):
    cost = GridPlanner(trav).cost_map(tuple(trav.cell_of(np.array(xy))))
    rng = np.random.default_rng(seed)
    pose = (xy[0], xy[1], 0.0)
    ctx = SearchContext.build(scene.cmap, scene.entropy(), pose, SENSOR_Z, trav, cost, exclude=exclude)
    target = choose_target(strategy, ctx, SearchOptions(radius=radius), rng)
    return target, cost


def neighbours8(mask: np.ndarray, i: int, j: int) -> bool:
    return bool(mask[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2].any())


@pytest.mark.parametrize("seed", range(6))
def test_frontier_is_the_nearest_reachable_free_cell_next_to_unknown(seed):
    scene, trav = blob_world(seed)
    free = np.argwhere(trav.free)
    xy = trav.centre(free[len(free) // 2])
    target, cost = choose_on(scene, trav, "frontier", xy)
    front = np.zeros(trav.shape, dtype=bool)
    for i, j in free:
        front[i, j] = neighbours8(trav.unknown, i, j) and np.isfinite(cost[i, j])
    assert np.array_equal(front, frontier_cells(trav) & np.isfinite(cost))
    if not front.any():
        assert target is None
        return
    pool = front & (cost >= 0.5) if (front & (cost >= 0.5)).any() else front
    cell = tuple(trav.cell_of(target.xy))
    assert target.kind == "frontier" and front[cell]
    assert cost[cell] == pytest.approx(cost[pool].min())
    # gaze towards the unknown neighbours
    unk = np.argwhere(trav.unknown[cell[0] - 1 : cell[0] + 2, cell[1] - 1 : cell[1] + 2]) - 1
    mean = (unk / np.linalg.norm(unk, axis=1, keepdims=True)).mean(axis=0)
    assert np.dot(mean, [math.cos(target.gaze_yaw), math.sin(target.gaze_yaw)]) > 0


@pytest.mark.parametrize("seed", range(4))
def test_frontier_when_unknown_is_blocked_but_not_inflated(seed):
    # build_traversability's rule: occupied columns inflated by the robot, unknown ones only blocked
    rng = np.random.default_rng(seed)
    shape, radius = (40, 30), 0.18
    occupied = ndimage.binary_dilation(rng.random(shape) < 0.02, iterations=1)
    unknown = ndimage.binary_dilation(rng.random(shape) < 0.01, iterations=2) & ~occupied
    free = inflate(occupied, E, radius) & ~unknown
    trav = TraversabilityGrid(free, occupied, unknown, (0.0, 0.0), E, radius)
    # brute force: free cells next to an unknown column that is clear of every wall's inflation
    occ = np.argwhere(np.pad(occupied, 1, constant_values=True)) - 1
    expected = np.zeros(shape, dtype=bool)
    for i, j in np.argwhere(free):
        for a in range(max(i - 1, 0), min(i + 2, shape[0])):
            for b in range(max(j - 1, 0), min(j + 2, shape[1])):
                clear = np.hypot(*(occ - [a, b]).T).min() > radius / E + 0.5
                expected[i, j] |= bool(unknown[a, b] and clear)
    assert expected.any()
    assert np.array_equal(frontier_cells(trav), expected)


def test_frontier_with_a_robot_radius_ignores_unknown_behind_walls():
    # a corridor y 1-2 m (walls at y 0.9 and 2.0 m); unknown at both ends (x < 0.5 and x > 5.5)
    # and behind the north wall
    nx, ny = 60, 30
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    occupied = (jj == 9) | (jj == 20)
    unknown = ((ii < 5) | (ii >= 55) | (jj > 20)) & ~occupied
    trav = TraversabilityGrid.from_blocked(occupied | unknown, (0.0, 0.0), E, 0.18, unknown=unknown)
    scene = Scene(nx, ny)
    # brute force: free cells next to cells that would be free if unknown were free
    would_be_free = inflate(occupied, E, 0.18)
    expected = np.zeros_like(trav.free)
    for i, j in np.argwhere(trav.free):
        expected[i, j] = neighbours8(would_be_free & ~trav.free, i, j)
    assert np.array_equal(frontier_cells(trav), expected)
    assert expected.any() and not expected[10:50].any()  # only at the ends, none along the north wall

    target, cost = choose_on(scene, trav, "frontier", (2.0, 1.5))  # nearer the west end
    assert target.xy[0] < 1.5 and math.cos(target.gaze_yaw) < -0.9
    assert cost[tuple(trav.cell_of(target.xy))] == pytest.approx(cost[expected].min())
    target, _ = choose_on(scene, trav, "frontier", (4.5, 1.5))
    assert target.xy[0] > 4.5 and math.cos(target.gaze_yaw) > 0.9
    # excluding the east end sends the robot west
    target, _ = choose_on(scene, trav, "frontier", (4.5, 1.5), exclude=[np.array([5.5, 1.5])])
    assert target.xy[0] < 1.5


# ---------------------------------------------------------------------------------------
# Random baseline
# ---------------------------------------------------------------------------------------
def test_random_targets_stay_reachable_within_twice_xi_and_repeat_with_the_seed():
    scene = Scene(60, 40)
    ii, jj = scene.columns()
    scene.set((ii < 40) & (jj < 30), 0.0, 0.04)
    scene.set((ii == 20) & (jj > 5), 1.0, 0.04)  # a wall with a gap at the south end
    xy, xi = (1.5, 1.5), 0.8
    trav, cost = scene.plan(xy)
    own = tuple(trav.cell_of(np.array(xy)))
    cells = set()
    for seed in range(40):
        target = scene.choose("random", xy, xi, seed=seed)
        assert target.kind == "random" and target.voxel is None
        cell = tuple(trav.cell_of(target.xy))
        assert trav.free[cell] and np.isfinite(cost[cell]) and cell != own
        assert np.linalg.norm(target.xy - np.array(xy)) <= 2 * xi + 1e-9
        assert -math.pi <= target.gaze_yaw <= math.pi
        again = scene.choose("random", xy, xi, seed=seed)
        assert np.array_equal(again.xy, target.xy) and again.gaze_yaw == target.gaze_yaw
        cells.add(cell)
    assert len(cells) > 20  # uniform over many cells, not a fixed one
