"""Traversability kept per tile and redone where the map changed: the coordinator's of the team
map, and each agent's of its own map (with the band's surely occupied columns of its probes).

:func:`swarm.navigation.traversability.build_traversability` reads the robot's height band of
every column of the map and lays a disc of the robot's radius around every position a robot
has stood on (swept floor), for each request. Here the band's column states (occupied,
unknown: ``grid_kernels.band_occupancy`` on a block of columns, the same per-column test)
are kept and redone for the tiles :class:`swarm.navigation.target_cache.ChangedTiles` reports,
and the swept floor is a count of discs per cell, raised and lowered as positions are kept
and dropped (``grid_kernels.disc_count``: the cells of ``disc_cells``). Only the inflation
by the robot's radius is a pass over the whole grid (compiled). The grid equals
``build_traversability``'s on the same map and swept positions (tests check it).
"""

from __future__ import annotations

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import SIGMA_MAX, SIGMA_MIN, expected_coverage
from swarm.navigation import grid_kernels as kernels
from swarm.navigation.target_cache import ChangedTiles, dirty_runs
from swarm.navigation.traversability import (
    FLOOR_CLEARANCE,
    FREE_THRESHOLD,
    TraversabilityGrid,
    band_layers,
    inflate,
)


class SweptFloor:
    """Cells (nx, ny) within ``radius`` (m) of a kept robot position: discs counted per cell.

    ``origin`` (x, y) and ``voxel`` (m) are the grid's. Not thread-safe (the caller's lock)."""

    def __init__(self, shape_xy: tuple[int, int], origin, voxel: float, radius: float) -> None:
        self.counts = np.zeros(shape_xy, dtype=np.int64)
        self.origin = (float(origin[0]), float(origin[1]))
        self.voxel = float(voxel)
        self.radius = float(radius)

    def _step(self, xy, step: int) -> None:
        kernels.disc_count(
            self.counts, float(xy[0]), float(xy[1]), *self.origin, self.voxel, self.radius, step
        )

    def add(self, xy) -> None:
        """A position (x, y) kept."""
        self._step(xy, 1)

    def drop(self, xy) -> None:
        """A kept position (x, y) dropped."""
        self._step(xy, -1)

    def mask(self) -> np.ndarray:
        """(nx, ny) bool: swept cells (``disc_cells`` of the kept positions)."""
        return self.counts > 0


class FloorCache:
    """The band's column states of a map per robot band and threshold, brought up to date per tile.

    Call :meth:`traversability` with the replica's lock held (it reads the changed tiles'
    voxels of ``cmap``) and from one thread at a time.
    """

    def __init__(self, changes: ChangedTiles, robot_radius: float) -> None:
        self.changes = changes
        self.robot_radius = float(robot_radius)
        self._bands: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def traversability(self, cmap: CoverageMap, robot_height: float, swept: np.ndarray) -> TraversabilityGrid:
        """``build_traversability(cmap, robot_height=robot_height, robot_radius=..., swept=...)``
        for the swept cells ``swept`` ((nx, ny) bool, :meth:`SweptFloor.mask`)."""
        grid = cmap.grid
        occupied, unknown = self.band(cmap, robot_height, FREE_THRESHOLD)
        origin = (float(grid.lo[0]), float(grid.lo[1]))
        unknown_now = unknown & ~swept
        free = inflate(occupied, grid.voxel, self.robot_radius) & ~unknown_now
        return TraversabilityGrid(free, occupied.copy(), unknown_now, origin, grid.voxel, self.robot_radius)

    def band(self, cmap: CoverageMap, robot_height: float, threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """``band_columns(cmap, FLOOR_CLEARANCE, robot_height, threshold)``: (occupied, unknown)
        (nx, ny) bool, the cache's own arrays (read them, do not write them)."""
        grid = cmap.grid
        layers = band_layers(cmap, FLOOR_CLEARANCE, robot_height)
        key = (int(layers[0]), int(layers[-1]) + 1, float(threshold))
        dirty = self.changes.take(f"band{key[0]}-{key[1]}@{key[2]!r}")
        if key not in self._bands:
            shape = grid.shape[:2]
            self._bands[key] = (np.zeros(shape, dtype=bool), np.zeros(shape, dtype=bool))
            dirty = np.ones(self.changes.tiles, dtype=bool)
        occupied, unknown = self._bands[key]
        tile = self.changes.tile
        for ti, a, b in dirty_runs(dirty):
            self._redo(cmap, key, occupied, unknown, ti * tile, a * tile, b * tile)
        return occupied, unknown

    def _redo(self, cmap, key, occupied, unknown, i0: int, j0: int, j1: int) -> None:
        """``band_columns`` of the columns [i0, i0 + tile) x [j0, j1)."""
        nx, ny, nz = cmap.grid.shape
        i1, j1 = min(i0 + self.changes.tile, nx), min(j1, ny)
        k0, k1, threshold = key
        lam = np.ascontiguousarray(cmap.lam.reshape(nx, ny, nz)[i0:i1, j0:j1, k0:k1]).ravel()
        eta = np.ascontiguousarray(cmap.eta.reshape(nx, ny, nz)[i0:i1, j0:j1, k0:k1]).ravel()
        shape = (int(i1 - i0), int(j1 - j0), int(k1 - k0))
        unk, occ, mu, sigma, column = kernels.band_occupancy(
            lam, eta, shape, 0, shape[2], cmap.known_threshold(), threshold, SIGMA_MIN, SIGMA_MAX
        )
        occ[column[expected_coverage(mu, sigma) >= threshold]] = True
        occupied[i0:i1, j0:j1] = occ.reshape(shape[:2])
        unknown[i0:i1, j0:j1] = unk.reshape(shape[:2])
