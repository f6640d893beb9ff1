"""Where one robot can drive: its traversability grids, refreshed from its local map.

:class:`Ground` is owned by :class:`robot_agent.explorer.Explorer`. It keeps the floor the robot
has swept (its own path, free whatever the map says), the traversability grid built from the
map (``swarm.navigation.traversability``) and, for the entropy strategy, the optimistic grid
that probes into unknown floor are planned on (``swarm.navigation.probing``).
"""

from __future__ import annotations

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.navigation.floor_cache import FloorCache, SweptFloor
from swarm.navigation.probing import SURE_COVERAGE, open_swept, optimistic_traversability
from swarm.navigation.targets import ExplorationTarget
from swarm.navigation.traversability import TraversabilityGrid, build_traversability, robot_band_top

SWEPT_STEP = 0.05  # m: the robot's path is noted each time it has moved this far


class Ground:
    """The traversability of a robot of ``robot_radius`` (m) with its camera at ``camera_height``
    (m); ``probes``: also keep the optimistic grid (the entropy strategy)."""

    def __init__(
        self, camera_height: float, robot_radius: float, probes: bool, floor: FloorCache | None = None
    ) -> None:
        self.robot_height = robot_band_top(camera_height)
        self.robot_radius = robot_radius
        self.probes = probes
        #: the band's column states kept per tile, redone where the map changed (None: a pass
        #: over the whole map's band at every refresh, the oracle the tests compare it with)
        self.floor = floor
        self.swept: list[tuple[float, float]] = []  # x-y (m) of the robot's path
        self._swept_floor: SweptFloor | None = None  # the discs of ``swept``, kept per cell
        self._kept = 0  # the positions of ``swept`` in ``_swept_floor``
        self.trav: TraversabilityGrid | None = None
        self.optimistic: TraversabilityGrid | None = None  # probes' grid (entropy strategy)

    def note_position(self, x: float, y: float) -> None:
        """Add (x, y) to the swept path when the robot has moved SWEPT_STEP since the last one."""
        if not self.swept:
            self.swept.append((x, y))
            return
        dx, dy = x - self.swept[-1][0], y - self.swept[-1][1]
        # either step alone past SWEPT_STEP decides it; hypot only of steps that cannot overflow
        if abs(dx) > SWEPT_STEP or abs(dy) > SWEPT_STEP or np.hypot(dx, dy) > SWEPT_STEP:
            self.swept.append((x, y))

    def refresh(self, cmap: CoverageMap) -> TraversabilityGrid:
        """Build the grids again from ``cmap``; returns the traversability grid."""
        swept = np.asarray(self.swept)
        surely = None
        if self.floor is None:
            trav = build_traversability(
                cmap, robot_height=self.robot_height, robot_radius=self.robot_radius, swept=swept
            )
        else:
            trav = self.floor.traversability(cmap, self.robot_height, self._swept_mask(cmap))
            if self.probes:
                surely = self.floor.band(cmap, self.robot_height, SURE_COVERAGE)[0]
        if self.probes:  # probes, and the way back through their doors
            self.optimistic = optimistic_traversability(cmap, trav, self.robot_height, surely=surely)
            trav = open_swept(trav, self.optimistic, swept)
        self.trav = trav
        return trav

    def _swept_mask(self, cmap: CoverageMap) -> np.ndarray:
        """(nx, ny) bool: the cells within the robot's radius of its swept path, kept up to date."""
        grid = cmap.grid
        if self._swept_floor is None:
            self._swept_floor = SweptFloor(grid.shape[:2], grid.lo[:2], grid.voxel, self.robot_radius)
        for xy in self.swept[self._kept :]:
            self._swept_floor.add(xy)
        self._kept = len(self.swept)
        return self._swept_floor.mask()

    def grid_for(self, target: ExplorationTarget, cmap: CoverageMap) -> TraversabilityGrid:
        """The grid a path to ``target`` is planned on (the optimistic one for a probe); built
        from ``cmap`` first if it never was."""
        if self.trav is None:
            self.refresh(cmap)
        return self.optimistic if target.kind == "probe" else self.trav
