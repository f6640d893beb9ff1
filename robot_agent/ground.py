"""Where one robot can drive: its traversability grids, refreshed from its local map.

:class:`Ground` is owned by :class:`robot_agent.explorer.Explorer`. It keeps the floor the robot
has swept (its own path, free whatever the map says), the traversability grid built from the
map (``swarm.navigation.traversability``) and, for the entropy strategy, the optimistic grid
that probes into unknown floor are planned on (``swarm.navigation.probing``).
"""

from __future__ import annotations

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.navigation.probing import open_swept, optimistic_traversability
from swarm.navigation.targets import ExplorationTarget
from swarm.navigation.traversability import TraversabilityGrid, build_traversability, robot_band_top

SWEPT_STEP = 0.05  # m: the robot's path is noted each time it has moved this far


class Ground:
    """The traversability of a robot of ``robot_radius`` (m) with its camera at ``camera_height``
    (m); ``probes``: also keep the optimistic grid (the entropy strategy)."""

    def __init__(self, camera_height: float, robot_radius: float, probes: bool) -> None:
        self.robot_height = robot_band_top(camera_height)
        self.robot_radius = robot_radius
        self.probes = probes
        self.swept: list[tuple[float, float]] = []  # x-y (m) of the robot's path
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
        trav = build_traversability(
            cmap, robot_height=self.robot_height, robot_radius=self.robot_radius, swept=swept
        )
        if self.probes:  # probes, and the way back through their doors
            self.optimistic = optimistic_traversability(cmap, trav, self.robot_height)
            trav = open_swept(trav, self.optimistic, swept)
        self.trav = trav
        return trav

    def grid_for(self, target: ExplorationTarget, cmap: CoverageMap) -> TraversabilityGrid:
        """The grid a path to ``target`` is planned on (the optimistic one for a probe); built
        from ``cmap`` first if it never was."""
        if self.trav is None:
            self.refresh(cmap)
        return self.optimistic if target.kind == "probe" else self.trav
