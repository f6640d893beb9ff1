"""The compiled traversability grid and planner graph equal their numpy/scipy oracles exactly."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.map.coverage_map import CoverageMap, prior_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.navigation.traversability import build_traversability, inflate
from tests.navigation_oracle import reference_build_traversability, reference_inflate


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
        for resolution, radius in ((0.1, 0.0), (0.1, 0.15), (0.1, 0.18), (0.05, 0.1), (1.0, 1.5), (0.1, 0.6)):
            np.testing.assert_array_equal(
                inflate(blocked, resolution, radius),
                reference_inflate(blocked, resolution, radius),
                err_msg=f"{shape} {density} {resolution} {radius}",
            )
