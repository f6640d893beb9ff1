"""A small scene for the exploration tests: a map, a sensor height (SENSOR_Z) and the robot in it."""

from __future__ import annotations

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy_cache import EntropyCache
from swarm.map.grid import Grid
from swarm.navigation.exploration import ExplorationTarget, SearchContext, SearchOptions, choose_target
from swarm.navigation.planner import GridPlanner
from swarm.navigation.traversability import TraversabilityGrid, build_traversability

E = 0.1


NZ = 8


SENSOR_Z = 0.45  # slab layer k0 = 4; the robot band [0.1, 0.5] m is layers 1..4


class Scene:
    """A small map whose columns are set whole: 'free' (mu 0), 'occ' (mu 1) or left unknown."""

    def __init__(self, nx: int, ny: int) -> None:
        self.grid = Grid((0.0, 0.0, 0.0), E, (nx, ny, NZ))
        self.cmap = CoverageMap(self.grid)

    def set(self, cols: np.ndarray, mu: float, sigma) -> None:
        """Columns ``cols`` (nx, ny) bool get belief N(mu, sigma) (sigma scalar or (nx, ny))."""
        lam = self.cmap.lam.reshape(self.grid.shape)
        eta = self.cmap.eta.reshape(self.grid.shape)
        s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), cols.shape)[cols]
        lam[cols] = (1.0 / s**2)[:, None]
        eta[cols] = (mu / s**2)[:, None]

    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        nx, ny, _ = self.grid.shape
        return np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")

    def entropy(self) -> np.ndarray:
        return EntropyCache.from_information(self.cmap.lam, self.cmap.eta).values

    def plan(self, xy: tuple[float, float]) -> tuple[TraversabilityGrid, np.ndarray]:
        trav = build_traversability(self.cmap, robot_radius=0.18)
        return trav, GridPlanner(trav).cost_map(tuple(trav.cell_of(np.array(xy))))

    def choose(
        self, strategy: str, xy, radius: float, seed: int = 0, exclude=(), **options
    ) -> ExplorationTarget | None:
        """``strategy``'s target from ``xy`` (yaw 0.3), ``options`` those of SearchOptions."""
        trav, cost = self.plan(xy)
        pose = (xy[0], xy[1], 0.3)
        ctx = SearchContext.build(self.cmap, self.entropy(), pose, SENSOR_Z, trav, cost, exclude=exclude)
        rng = np.random.default_rng(seed)
        return choose_target(strategy, ctx, SearchOptions(radius=radius, **options), rng)
