"""How a robot gives way to its teammates (the rule of :mod:`swarm.navigation.teammates`).

:class:`GivingWay` is owned by :class:`robot_agent.explorer.Explorer`: it holds where the
teammates were last seen (``teammates``), this robot's rank, the frames waited in a row and the
targets set aside for a while, and says what to do when a teammate's keep-out disc lies on the
path ahead: wait, drive around it, or give the target up (set aside, not for ever).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from enum import Enum

import numpy as np

from swarm.navigation.planner import GridPlanner
from swarm.navigation.targets import ExplorationTarget
from swarm.navigation.teammates import Disc, Teammates, block_teammates, blocking_teammate
from swarm.navigation.traversability import TraversabilityGrid

# a teammate in the way: frames a robot waits before it gives its target up, when the teammate
# ranks before it (it yields) and when after (it holds on longer, so that the other yields first)
YIELD_FRAMES = 4
HOLD_FRAMES = 16
DEFER_S = 20.0  # s: a target given up for a teammate is set aside this long, not for ever
AROUND_EVERY = 4  # frames between attempts to drive around a teammate that ranks after this robot


def robot_rank(robot_ids: Sequence[str], robot: str) -> tuple[int, str]:
    """The rank of ``robot`` for giving way (lower goes first): its place in the mission's robot
    list; robots beyond the list (an agent the mission does not name, a status with an id
    nobody configured) rank after it, in the order of their ids."""
    ids = list(robot_ids)
    return (ids.index(robot), "") if robot in ids else (len(ids), robot)


class Way(Enum):
    """What :meth:`GivingWay.make_way` says to do about a teammate in the way."""

    AROUND = "around"  # drive the returned path around it
    WAIT = "wait"  # stand still this frame
    GIVE_UP = "give up"  # the target is set aside: choose another


class GivingWay:
    """Giving way to the ``teammates`` of robot ``robot_id`` of a mission of ``robot_ids``."""

    def __init__(self, robot_ids: Sequence[str], robot_id: str, teammates: Teammates) -> None:
        self.robot_ids = list(robot_ids)
        self.teammates = teammates
        self.priority = robot_rank(self.robot_ids, robot_id)  # lowest first: the others yield to it
        self.now: float | None = None  # the frame's mission time (s); None: teammates ignored
        self.deferred: list[tuple[np.ndarray, float]] = []  # (target x-y, set aside until t)
        self.waited = 0  # frames waited in a row for a teammate in the way

    def discs(self, here: np.ndarray | None = None) -> list[Disc]:
        """The teammates' fresh keep-out discs (``Teammates.discs``; with ``here``, those the
        robot stands in shrunk, to plan from its cell); none without a frame time."""
        return [] if self.now is None else self.teammates.discs(self.now, here)

    def make_way(
        self,
        here: np.ndarray,
        discs: list[Disc],
        mate: str,
        target: ExplorationTarget,
        grid: Callable[[], TraversabilityGrid],
    ) -> tuple[Way, np.ndarray | None]:
        """A teammate's disc (``mate``'s) lies on the path ahead. One that comes first in the
        robot list: wait, and after YIELD_FRAMES give the target up. One that comes after: drive
        around it if a path on ``grid()`` (the target's grid, called only then) does, else
        wait, HOLD_FRAMES at most. Returns what to do and, for AROUND, the path (m, (n, 2))."""
        self.waited += 1
        first = robot_rank(self.robot_ids, mate) < self.priority
        if not first and self.waited % AROUND_EVERY == 1:
            path = GridPlanner(block_teammates(grid(), self.discs(here))).plan(here, target.xy)
            if path is not None and len(path) >= 2 and blocking_teammate(path[1:], here, discs) is None:
                return Way.AROUND, path
        if self.waited > (YIELD_FRAMES if first else HOLD_FRAMES):
            self.set_aside(target)
            self.waited = 0
            return Way.GIVE_UP, None
        return Way.WAIT, None

    def set_aside(self, target: ExplorationTarget) -> None:
        """Set ``target`` aside for DEFER_S (teammates stand in its way)."""
        self.deferred.append((np.asarray(target.xy, dtype=np.float64), (self.now or 0.0) + DEFER_S))

    def set_aside_points(self) -> list[np.ndarray]:
        """The x-y of the targets set aside for teammates that are still set aside now."""
        self.deferred = [(xy, until) for xy, until in self.deferred if self.now is None or until > self.now]
        return [xy for xy, _until in self.deferred]


def reachable_without_teammates(grid: TraversabilityGrid, start: np.ndarray, goal: np.ndarray) -> bool:
    """Whether a path from ``start`` to ``goal`` (x-y, m) exists on ``grid`` alone (no teammates)."""
    path = GridPlanner(grid).plan(start, goal)
    return path is not None and len(path) >= 2
