"""The compiled traversability grid and planner graph equal their numpy/scipy oracles exactly."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.map.coverage_map import CoverageMap, prior_information
from swarm.map.entropy import SIGMA_MAX, SIGMA_MIN, expected_coverage
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.navigation import grid_kernels as kernels
from swarm.navigation.grid_kernels import CERTAIN_BOUND
from swarm.navigation.planner import GridPlanner, cost_map
from swarm.navigation.probing import optimistic_traversability
from swarm.navigation.traversability import TraversabilityGrid, build_traversability, inflate
from swarm.navigation.view_kernels import clear_line, stand_for
from tests.support.navigation_oracle import (
    reference_build_traversability,
    reference_clear,
    reference_graph,
    reference_inflate,
    reference_stand_for,
    reference_surely_occupied,
    reference_tree,
)
from tests.support.numba_cache import second_run_cache_statistics


def random_map(rng: np.random.Generator, shape=(41, 29, 9), voxel: float = 0.1) -> CoverageMap:
    """A map of free, wall and partly seen columns: voxels at the prior, exactly at the known
    threshold (not known), or known with means near 0 (free) or anywhere in and out of [0, 1]."""
    cmap = CoverageMap(Grid((-0.3, 0.7, 0.0), voxel, shape), SensorModel())
    lam0, _ = prior_information(cmap.sensor)
    n = cmap.grid.size
    kinds = rng.choice(3, shape[0] * shape[1], p=[0.9, 0.02, 0.08])  # 0 free, 1 wall, 2 partly seen
    column = np.repeat(kinds, shape[2])
    lam = lam0 * (1 + 10 ** np.where(column == 0, rng.uniform(3, 5, n), rng.uniform(-4, 4, n)))
    kind = rng.integers(0, 3, n)
    lam[(column == 2) & (kind == 0)] = lam0
    lam[(column == 2) & (kind == 1)] = cmap.known_threshold()  # exactly at the threshold: not known
    mu = np.where(column == 0, rng.uniform(-0.05, 0.1, n), rng.uniform(-0.5, 1.5, n))
    cmap.lam = lam.astype(np.float32)
    cmap.eta = (mu * cmap.lam).astype(np.float32)
    return cmap


@pytest.mark.parametrize("seed", range(6))
def test_build_traversability_equals_the_numpy_oracle(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cmap = random_map(rng)
    assert 0 < cmap.known_mask().sum() < cmap.grid.size
    swept = np.vstack([rng.uniform(-1.0, 3.0, (5, 2)), rng.uniform(-1.0, 3.0, (1, 2)).repeat(3, axis=0)])
    for kwargs in (
        {},
        {"robot_radius": 0.0, "free_threshold": 0.5},
        {"robot_radius": 0.25, "margin": 0.05, "swept": swept, "robot_height": 0.8},
        {"robot_radius": 0.15, "swept": swept[:1], "floor_clearance": 0.25, "robot_height": 0.3},
    ):
        fast = build_traversability(cmap, **kwargs)
        slow = reference_build_traversability(cmap, **kwargs)
        for name in ("free", "occupied", "unknown"):
            np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
        assert fast.free.any() and fast.occupied.any() and fast.unknown.any()
        for name in ("origin", "resolution", "robot_radius"):
            assert getattr(fast, name) == getattr(slow, name)


@pytest.mark.parametrize("seed", range(4))
def test_inflate_equals_the_distance_transform(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers(1, 40, 2))
    for density in (0.0, 0.02, 0.2, 0.9):
        blocked = rng.random(shape) < density
        # Radii whose threshold falls on a distance exactly (ties are blocked) and between.
        for resolution, radius in (
            (0.1, 0.0),
            (0.1, 0.15),
            (0.1, 0.18),
            (0.05, 0.1),
            (1.0, 1.5),
            (0.1, 0.6),
            (0.1, 1.03),
        ):
            np.testing.assert_array_equal(
                inflate(blocked, resolution, radius),
                reference_inflate(blocked, resolution, radius),
                err_msg=f"{shape} {density} {resolution} {radius}",
            )


@pytest.mark.parametrize("seed", range(4))
def test_planner_graph_and_trees_equal_the_scipy_oracle(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for shape, density in (
        ((1, 1), 1.0),
        ((1, 9), 0.8),
        ((9, 1), 0.8),
        ((30, 22), 0.75),
        ((25, 40), 0.95),
        ((17, 23), 1.0),
    ):
        free = rng.random(shape) < density
        planner = GridPlanner(free)
        # The same edges as the oracle's forward graph and its transpose ...
        oracle = reference_graph(free)
        both = (oracle + oracle.T).tocoo()
        ours = planner._graph.tocoo()
        edges = sorted(zip(ours.row, ours.col, ours.data, strict=True))
        assert edges == sorted(zip(both.row, both.col, both.data, strict=True))
        # ... each row listing the nodes after it, then those before it, each increasing
        for row in range(planner._graph.shape[0]):
            cols = planner._graph.indices[planner._graph.indptr[row] : planner._graph.indptr[row + 1]]
            after, before = cols[cols > row], cols[cols < row]
            np.testing.assert_array_equal(cols, np.concatenate([np.sort(after), np.sort(before)]))
        cells = np.argwhere(free)
        if len(cells) == 0:
            continue
        for start in cells[rng.integers(0, len(cells), 3)]:
            node = planner._node(tuple(start))
            dist, pred = reference_tree(free, node)
            cost = planner.cost_map(tuple(start))  # then a path from the same start: one Dijkstra
            np.testing.assert_array_equal(cost.ravel()[planner._cell_of], dist)
            for goal in cells[rng.integers(0, len(cells), 5)]:
                path = planner.plan_cells(tuple(start), tuple(goal))
                g = planner._node(tuple(goal))
                if not np.isfinite(dist[g]):
                    assert path is None
                    continue
                chain = [g]
                while chain[-1] != node:
                    chain.append(int(pred[chain[-1]]))
                expected = np.argwhere(free.ravel())[chain[::-1], 0]
                np.testing.assert_array_equal(path[:, 0] * shape[1] + path[:, 1], expected)


def test_segment_is_free_checks_exactly_the_segment_cells() -> None:
    rng = np.random.default_rng(7)
    free = rng.random((12, 9)) < 0.85
    grid = TraversabilityGrid(free, ~free, np.zeros_like(free), (-0.35, 0.2), 0.1)
    ends = np.vstack(
        [
            rng.uniform(-0.5, 1.0, (300, 2)),
            # On cell corners and lines, and just beside them, to exercise the corner rule.
            -0.35 + 0.1 * rng.integers(-1, 13, (200, 2)) * np.array([1.0, 1.0]) + [0.0, 0.55],
            grid.centre(rng.integers(0, 12, (100, 2))) + rng.choice([0.0, 1e-10, -0.05], (100, 2)),
        ]
    )
    seen = set()
    for k in range(0, len(ends) - 1):
        a, b = ends[k], ends[(k * 7 + 3) % len(ends)]
        expected = bool(np.all(grid.is_free(grid.segment_cells(a, b))))
        assert grid.segment_is_free(a, b) == expected, (a, b)
        seen.add(expected)
    assert seen == {True, False}
    for bad in (np.nan, np.inf, -np.inf):
        assert not grid.segment_is_free(grid.centre(np.argwhere(free)[0]), np.array([bad, 0.5]))


@pytest.mark.parametrize("threshold", [0.2, 0.5, 0.9])
def test_band_occupancy_bound_never_decides_against_expected_coverage(threshold: float) -> None:
    """Voxels the bound decides (occupied or free) get the answer E[C] gives; the rest are returned."""
    rng = np.random.default_rng(3)
    n = 200_000
    sigma = np.concatenate([10 ** rng.uniform(-10, -0.5, n // 2), rng.uniform(0.04, 0.06, n // 2)])
    mu = np.where(
        rng.random(n) < 0.5,
        threshold + rng.choice([-1, 1], n) * CERTAIN_BOUND * sigma * rng.uniform(0.9, 1.1, n),
        rng.uniform(-3, 4, n),
    )
    sigma[:4] = 1e-3  # where the bound would decide, ...
    lam = (1.0 / sigma**2).astype(np.float32)
    eta = (mu * lam).astype(np.float32)
    eta[:3], lam[3] = [np.inf, -np.inf, np.nan], np.inf  # ... non-finite beliefs (E[C] NaN: not occupied)
    unknown, occupied, m, s, column = kernels.band_occupancy(
        lam, eta, (n, 1, 1), 0, 1, np.float32(0.0), threshold, SIGMA_MIN, SIGMA_MAX
    )
    assert not unknown.any()
    exact = (
        expected_coverage(eta.astype(np.float64) / lam, 1.0 / np.sqrt(lam.astype(np.float64))) >= threshold
    )
    decided = np.ones(n, bool)
    decided[column] = False
    np.testing.assert_array_equal(occupied[decided], exact[decided])
    assert not occupied[~decided].any()
    np.testing.assert_array_equal(expected_coverage(m, s) >= threshold, exact[column])
    assert 0.05 * n < len(column) < 0.8 * n  # the bound decides many, not all


@pytest.mark.parametrize("seed", range(6))
def test_the_graphless_cost_map_equals_the_planners_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(1, 70)), int(rng.integers(1, 70)))
    free = rng.random(shape) < rng.uniform(0.3, 0.95)
    for resolution in (1.0, 0.1, 0.05):
        grid = TraversabilityGrid(free, ~free, np.zeros_like(free), (0.0, 0.0), resolution)
        starts = [(int(rng.integers(0, shape[0])), int(rng.integers(0, shape[1]))) for _ in range(3)]
        for start in [*starts, (-1, 0), (shape[0], 0)]:
            assert np.array_equal(cost_map(grid, start), GridPlanner(grid).cost_map(start))
    assert np.array_equal(cost_map(free, (0, 0)), GridPlanner(free).cost_map((0, 0)))  # a bare array


@pytest.mark.slow
def test_a_second_process_loads_the_navigation_kernels_from_numbas_cache() -> None:
    """Numba's own statistics after the agent's warm-up of planning: a fresh interpreter hits the cache."""
    stats = second_run_cache_statistics(
        "from swarm.map import coverage_map as c\n"
        "from swarm.navigation import grid_kernels as k, planner, view_kernels as v\n"
        "planner.warm_up()",
        "(k.band_occupancy, k.inflate_blocked, k.disc_cells, k.grid_graph, k.segment_is_free,"
        " k.grid_distances, k.disc_count, c.add_information, v.stand_for)",
    )
    assert len(stats) == 9
    for name, (hits, misses) in stats.items():
        assert hits >= 1 and misses == 0, (name, stats)


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_stand_search_equals_its_numpy_oracle(seed):
    # Random reachability, walls and path costs with many ties (integer costs), random
    # windows and distance bands (some empty, some wider than the grid), every column of the
    # grid, some cells to avoid: the same stand (or none) and the same line-of-sight verdicts.
    rng = np.random.default_rng(seed)
    nx, ny, voxel = 37, 23, 0.1
    usable = rng.random((nx, ny)) < 0.6
    opaque = rng.random((nx, ny)) < 0.08
    cost = np.where(usable, rng.integers(0, 12, (nx, ny)).astype(np.float64), np.inf)
    avoid = rng.random((nx, ny)) < 0.05 if seed % 2 else np.zeros((nx, ny), bool)
    cx = -0.3 + (np.arange(nx) + 0.5) * voxel
    cy = 0.7 + (np.arange(ny) + 0.5) * voxel
    start = (int(rng.integers(nx)), int(rng.integers(ny)))
    found = 0
    for i in range(nx):
        for j in range(ny):
            d_lo = float(rng.uniform(0.0, 1.5))
            d_hi = float(d_lo + rng.uniform(-0.2, 2.5))
            half = int(np.ceil(max(d_hi, 0.0) / voxel)) + 1
            expected = reference_stand_for(usable, avoid, cost, start, cx, cy, opaque, i, j, d_lo, d_hi, half)
            a, b = stand_for(usable, avoid, cost, start[0], start[1], cx, cy, opaque, i, j, d_lo, d_hi, half)
            assert (None if a < 0 else (a, b)) == expected, (i, j, d_lo, d_hi)
            found += expected is not None
            a, b = int(rng.integers(nx)), int(rng.integers(ny))
            assert clear_line(opaque, a, b, i, j) == reference_clear(opaque, a, b, i, j)
    assert 0 < found < nx * ny  # both outcomes were exercised


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("sure", [0.2, 0.5, 0.9])
def test_the_optimistic_grids_surely_occupied_columns_equal_the_numpy_oracle(seed, sure):
    cmap = random_map(np.random.default_rng(seed))
    trav = build_traversability(cmap, robot_height=0.5, robot_radius=0.18)
    optimistic = optimistic_traversability(cmap, trav, 0.5, sure=sure)
    expected = reference_surely_occupied(cmap, 0.1, 0.5, sure)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(optimistic.occupied, expected)
    np.testing.assert_array_equal(optimistic.free, inflate(expected, cmap.grid.voxel, 0.18) | trav.free)
