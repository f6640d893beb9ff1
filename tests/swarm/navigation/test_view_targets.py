"""3-D frontier views (swarm.navigation.view_targets): targets above the sensor slab."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_cache import EntropyCache
from swarm.map.grid import Grid
from swarm.navigation import planner, view_targets
from swarm.navigation.exploration import SearchOptions, choose_target, last_look_target
from swarm.navigation.planner import GridPlanner
from swarm.navigation.search_context import OPAQUE_COVERAGE, SearchContext
from swarm.navigation.traversability import build_traversability
from swarm.navigation.view_kernels import stand_for
from swarm.navigation.view_targets import RESTAND_RADIUS, CameraReach, uncertain_voxels, view_target

GRID = Grid((0.0, 0.0, 0.0), 0.1, (40, 20, 16))  # 4 m x 2 m x 1.6 m
HALF_V = math.atan(0.5 * 120 / (0.5 * 160 / math.tan(math.radians(30))))  # the default rig's


def _known_below(z_known: float) -> CoverageMap:
    """Every voxel below ``z_known`` known free; the ones above unknown."""
    cmap = CoverageMap(GRID)
    z = GRID.lo[2] + (np.arange(GRID.shape[2]) + 0.5) * GRID.voxel
    lam = cmap.lam.reshape(GRID.shape)
    eta = cmap.eta.reshape(GRID.shape)
    lam[:, :, z < z_known] = 1.0 / 0.02**2
    eta[:, :, z < z_known] = 0.0
    return cmap


def _choose(strategy, cmap, camera, tried=(), pose=(1.0, 1.0, 0.0)):
    trav = build_traversability(cmap, robot_height=0.5, robot_radius=0.18)
    cell = tuple(int(c) for c in trav.cell_of(np.array(pose[:2])))
    cost = GridPlanner(trav).cost_map(cell)
    entropy = np.zeros(GRID.size)  # no eq. 35 gradient to follow
    rng = np.random.default_rng(0)
    ctx = SearchContext.build(cmap, entropy, pose, 0.4, trav, cost)
    return choose_target(strategy, ctx, SearchOptions(radius=1.5, camera=camera), rng, tried=tried)


@pytest.mark.parametrize(
    ("tilt", "d_min"), [(35.0, 0.65 / math.tan(HALF_V + math.radians(35))), (0.0, 0.65 / math.tan(HALF_V))]
)
def test_unknown_air_above_the_slab_is_looked_at_from_where_the_band_reaches_it(tilt, d_min):
    cmap = _known_below(1.0)  # the slab and the floor known, z >= 1.0 unknown
    camera = CameraReach(-HALF_V, HALF_V + math.radians(tilt), 5.0)
    # without the camera's band the strategies see nothing left: the robot would stop here
    assert _choose("entropy", cmap, None) is None
    assert _choose("frontier", cmap, None) is None
    for strategy, kind in (("entropy", "view"), ("frontier", "frontier3d")):
        target = _choose(strategy, cmap, camera)
        assert target is not None and target.kind == kind
        i, j, k = np.unravel_index(target.voxel, GRID.shape)
        column = GRID.lo[:2] + (np.array([i, j]) + 0.5) * 0.1
        d = np.linalg.norm(column - target.xy)
        assert k == 10  # the first unknown layer, z 1.0-1.1 m (centre 0.65 m above the camera)
        assert d_min - 1e-9 <= d <= 5.0
        assert math.atan2(0.65, d) <= camera.elevation_hi + 1e-9  # in the band
        look = column - target.xy
        assert math.cos(math.atan2(look[1], look[0]) - target.gaze_yaw) == pytest.approx(1.0)
        assert np.linalg.norm(target.xy - np.array([1.0, 1.0])) < 0.6  # the nearest such place


def test_columns_already_looked_at_are_not_chosen_again():
    cmap = _known_below(1.0)
    camera = CameraReach(-HALF_V, HALF_V + math.radians(35), 5.0)
    everywhere = [GRID.lo[:2] + (np.array([i, j]) + 0.5) * 0.1 for i in range(40) for j in range(20)]
    assert _choose("entropy", cmap, camera, tried=everywhere) is None
    first = _choose("entropy", cmap, camera)
    i, j, _ = np.unravel_index(first.voxel, GRID.shape)
    again = _choose("entropy", cmap, camera, tried=[GRID.lo[:2] + (np.array([i, j]) + 0.5) * 0.1])
    assert again is not None and again.voxel != first.voxel


def test_unknown_air_out_of_range_gives_nothing():
    cmap = _known_below(1.0)
    short = CameraReach(-HALF_V, HALF_V, 0.6)  # 0.65 m above the camera: out of a 0.6 m range
    assert _choose("entropy", cmap, short) is None


def _one_unknown_column(i: int = 20, j: int = 10, z_from: float = 1.0, more=()) -> CoverageMap:
    """Every voxel known free but column (i, j) (and the columns ``more``) from ``z_from`` up."""
    cmap = _known_below(10.0)
    z = GRID.lo[2] + (np.arange(GRID.shape[2]) + 0.5) * GRID.voxel
    prior = CoverageMap(GRID)
    for a, b in [(i, j), *more]:
        cmap.lam.reshape(GRID.shape)[a, b, z >= z_from] = prior.lam[0]
        cmap.eta.reshape(GRID.shape)[a, b, z >= z_from] = prior.eta[0]
    return cmap


def _choose_frontier(cmap, camera, tried, stands, max_looks, pose=(1.0, 1.0, 0.0)):
    trav = build_traversability(cmap, robot_height=0.5, robot_radius=0.18)
    cell = tuple(int(c) for c in trav.cell_of(np.array(pose[:2])))
    cost = GridPlanner(trav).cost_map(cell)
    entropy = np.zeros(GRID.size)
    rng = np.random.default_rng(0)
    ctx = SearchContext.build(cmap, entropy, pose, 0.4, trav, cost)
    options = SearchOptions(radius=1.5, camera=camera, max_looks=max_looks)
    return choose_target("frontier", ctx, options, rng, tried=tried, stands=stands)


def test_a_frontier_column_left_unknown_is_looked_at_again_from_other_cells_then_given_up():
    cmap = _one_unknown_column()
    assert (~cmap.known_mask()).sum() == 6  # z 1.0-1.6 m of column (20, 10): x 2.05, y 1.05
    camera = CameraReach(-HALF_V, HALF_V + math.radians(35), 5.0)
    column = np.array([2.05, 1.05])
    tried, stands = [], []
    for _ in range(3):
        target = _choose_frontier(cmap, camera, tried, stands, max_looks=3)
        assert target is not None and target.kind == "frontier3d"
        i, j, k = np.unravel_index(target.voxel, GRID.shape)
        assert (i, j, k) == (20, 10, 10)
        # each look from a cell farther than RESTAND_RADIUS from the earlier ones
        for s in stands:
            assert np.linalg.norm(target.xy - s) > RESTAND_RADIUS
        d = np.linalg.norm(column - target.xy)
        assert math.atan2(0.65, d) <= camera.elevation_hi + 1e-9  # in the band
        tried.append(column)
        stands.append(target.xy)
    # three looks and still unknown: given up (the search is finite)
    assert _choose_frontier(cmap, camera, tried, stands, max_looks=3) is None
    # one look (the entropy strategy's rule, and the default) gives it up at once
    assert _choose_frontier(cmap, camera, tried[:1], stands[:1], max_looks=1) is None
    assert _choose_frontier(cmap, camera, tried[:1], None, max_looks=1) is None
    assert _choose("entropy", cmap, camera, tried=tried[:1]) is None


def test_retried_views_reject_bad_arguments():
    cmap = _one_unknown_column()
    camera = CameraReach(-HALF_V, HALF_V + math.radians(35), 5.0)
    with pytest.raises(ValueError, match="max_looks"):
        _choose_frontier(cmap, camera, [], [], max_looks=0)
    with pytest.raises(ValueError, match="one stand per look"):
        _choose_frontier(cmap, camera, [np.array([2.05, 1.05])], [], max_looks=3)


def test_never_looked_columns_come_before_second_looks_however_far():
    # Column A (x 1.35) near the robot (x 0.5) was looked at once; column B (x 3.05) never
    # and, with a 1.5 m range, seen only from 1.3 m of path or more: B first, though a second
    # look at A from another cell (0.3 m away) would be nearer; then A again.
    cmap = _one_unknown_column(13, 10, more=[(30, 10)])
    camera = CameraReach(-HALF_V, HALF_V + math.radians(35), 1.5)
    a, b = np.array([1.35, 1.05]), np.array([3.05, 1.05])
    pose = (0.55, 1.05, 0.0)
    first = _choose_frontier(cmap, camera, [], [], max_looks=3, pose=pose)
    assert np.unravel_index(first.voxel, GRID.shape)[:2] == (13, 10)  # the nearest, A
    assert np.allclose(first.xy, pose[:2])  # from where the robot stands
    second = _choose_frontier(cmap, camera, [a], [first.xy], max_looks=3, pose=pose)
    assert np.unravel_index(second.voxel, GRID.shape)[:2] == (30, 10)  # B, never looked at
    assert np.linalg.norm(second.xy - b) <= 1.5
    third = _choose_frontier(cmap, camera, [a, b], [first.xy, second.xy], max_looks=3, pose=pose)
    assert np.unravel_index(third.voxel, GRID.shape)[:2] == (13, 10)  # A again, from elsewhere
    assert np.linalg.norm(third.xy - first.xy) > RESTAND_RADIUS


def test_last_looks_go_to_uncertain_known_voxels_and_only_to_those_with_bits_left():
    # Everything known: below 1 m surely free, above it seen once, faintly (sigma 0.5 around
    # E[C] 0.5). No 3-D frontier is left, so the strategies stop; the last look goes to the
    # nearest uncertain column in view, and to none when min_bits is above what they hold.
    # (Entropies in bits over the discretised coverage: the prior about 7, sigma 0.02 2.4.)
    cmap = _known_below(1.0)
    lam = cmap.lam.reshape(GRID.shape)
    eta = cmap.eta.reshape(GRID.shape)
    lam[:, :, 10:] = 4.0
    eta[:, :, 10:] = 2.0
    entropy = EntropyCache.from_information(cmap.lam, cmap.eta).values
    camera = CameraReach(-HALF_V, HALF_V + math.radians(35), 5.0)
    assert _choose("entropy", cmap, camera) is None
    pose = (1.0, 1.0, 0.0)
    trav = build_traversability(cmap, robot_height=0.5, robot_radius=0.18)
    cost = GridPlanner(trav).cost_map(tuple(int(c) for c in trav.cell_of(np.array(pose[:2]))))
    faint = float(entropy.reshape(GRID.shape)[0, 0, 10])
    sure = float(entropy.reshape(GRID.shape)[0, 0, 0])
    assert sure < 3.5 < faint
    ctx = SearchContext.build(cmap, entropy, pose, 0.4, trav, cost)
    target = last_look_target(ctx, camera, min_bits=3.5)
    assert target is not None and target.kind == "last look"
    i, j, k = np.unravel_index(target.voxel, GRID.shape)
    assert k == 10  # the lowest uncertain voxel of its column, on the free air below
    assert np.linalg.norm(target.xy - np.array(pose[:2])) < 0.6
    # the same column is not looked at twice; nothing holds more than ``faint`` bits
    column = GRID.lo[:2] + (np.array([i, j]) + 0.5) * GRID.voxel
    again = last_look_target(ctx, camera, 3.5, tried=[column])
    assert again is not None and again.voxel != target.voxel
    assert last_look_target(ctx, camera, min_bits=faint + 0.1) is None
    voxels = uncertain_voxels(ctx, entropy, 3.5)
    assert voxels[:, :, 10].all() and not voxels[:, :, :10].any()
    with pytest.raises(ValueError, match="shape"):
        view_target(ctx, camera, voxels=voxels[:, :, :5])


def test_the_planners_warm_up_compiles_the_stand_search_a_real_view_choice_runs():
    # the agent's warm-up (planner.warm_up) must compile stand_for for the argument types of a
    # real choice, or the first 3-D view of a mission compiles it then (tens of seconds on a
    # busy machine: the world declared the agent dead)
    planner.warm_up()
    warmed = list(stand_for.signatures)
    assert warmed
    camera = CameraReach(-HALF_V, HALF_V + math.radians(35.0), 5.0)
    assert _choose("entropy", _known_below(1.0), camera).kind == "view"
    assert list(stand_for.signatures) == warmed


@pytest.mark.parametrize("chunk", [1, 7 * GRID.shape[1] * GRID.shape[2] + 5, GRID.size])
def test_free_voxels_slab_by_slab_equal_the_whole_map_formula(monkeypatch, chunk):
    rng = np.random.default_rng(chunk)
    cmap = CoverageMap(GRID)
    seen = rng.random(GRID.size) < 0.6
    cmap.lam[seen] = rng.uniform(10.0, 3000.0, seen.sum()).astype(np.float32)
    cmap.eta[seen] = cmap.lam[seen] * rng.uniform(0.0, 1.0, seen.sum()).astype(np.float32)
    monkeypatch.setattr(view_targets, "FREE_CHUNK", chunk)
    known, near_free = view_targets._known_and_near_free(type("Ctx", (), {"cmap": cmap})())
    whole = cmap.known_mask() & (expected_coverage(cmap.mean(), cmap.sigma()) < OPAQUE_COVERAGE)
    free = whole.reshape(GRID.shape)
    expected = np.zeros(GRID.shape, dtype=bool)
    expected[1:] |= free[:-1]
    expected[:-1] |= free[1:]
    expected[:, 1:] |= free[:, :-1]
    expected[:, :-1] |= free[:, 1:]
    expected[:, :, 1:] |= free[:, :, :-1]
    expected[:, :, :-1] |= free[:, :, 1:]
    assert np.array_equal(known, cmap.known_mask().reshape(GRID.shape))
    assert np.array_equal(near_free, expected) and 0 < near_free.sum() < near_free.size
