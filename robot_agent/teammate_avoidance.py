"""How a robot's explorer gives way to its teammates (the rule of :mod:`swarm.navigation.teammates`).

:class:`TeammateAvoidance` is the part of :class:`robot_agent.explorer.Explorer` that acts on the
teammates' keep-out discs: waiting, driving around a teammate, yielding by rank, and setting a
target aside for a while when teammates stand in its way. It is a mixin: it works on the
explorer's own state (``teammates``, ``now``, ``priority``, ``waited``, ``deferred``, the
follower, the traversability grids and the target), which ``Explorer.__init__`` sets up.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from robot_agent.decision import Decision
from swarm.navigation.exploration import ExplorationTarget
from swarm.navigation.path_follower import DriveWatch
from swarm.navigation.planner import GridPlanner
from swarm.navigation.teammates import block_teammates, blocking_teammate

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


class TeammateAvoidance:
    """Giving way to teammates; mixed into :class:`robot_agent.explorer.Explorer`."""

    def _teammate_discs(self, here: np.ndarray | None = None) -> list:
        """The teammates' fresh keep-out discs (``Teammates.discs``; with ``here``, those the
        robot stands in shrunk, to plan from its cell); none without a frame time."""
        return [] if self.now is None else self.teammates.discs(self.now, here)

    def _make_way(self, here: np.ndarray, yaw: float, discs: list, mate: str) -> Decision:
        """A teammate's disc lies on the path ahead. One that comes first in the robot list:
        wait, and after YIELD_FRAMES set the target aside and choose another. One that comes
        after: drive around it if a path does, else wait, HOLD_FRAMES at most."""
        self.waited += 1
        self.progress = DriveWatch(here)  # waiting is not being stuck
        first = robot_rank(self.mission.robot_ids, mate) < self.priority
        if not first and self.waited % AROUND_EVERY == 1:
            if self.trav is None:
                self._refresh_traversability()
            base = self.optimistic if self.target.kind == "probe" else self.trav
            path = GridPlanner(block_teammates(base, self._teammate_discs(here))).plan(here, self.target.xy)
            if path is not None and len(path) >= 2 and blocking_teammate(path[1:], here, discs) is None:
                self.follower.set_path(path)
                command = self.follower.command(here[0], here[1], yaw)
                return Decision(command.v, command.omega, "drive", self._target_xy())
        if self.waited > (YIELD_FRAMES if first else HOLD_FRAMES):
            self.give_ups["teammate"] += 1
            self._set_aside_target(self.target)
            self.target = None
            self.state = "choose"
            self.waited = 0
            return Decision(0.0, 0.0, "choose")
        return Decision(0.0, 0.0, "wait", self._target_xy())

    def _set_aside_target(self, target: ExplorationTarget) -> None:
        self.deferred.append((np.asarray(target.xy, dtype=np.float64), (self.now or 0.0) + DEFER_S))

    def _set_aside(self) -> list[np.ndarray]:
        """The targets set aside for teammates that are still set aside now."""
        self.deferred = [(xy, until) for xy, until in self.deferred if self.now is None or until > self.now]
        return [xy for xy, _until in self.deferred]

    def _reachable_without_teammates(self, start: np.ndarray, target: ExplorationTarget) -> bool:
        """Whether a path to the target exists on the map's grid alone (no teammates)."""
        base = self.optimistic if target.kind == "probe" else self.trav
        path = GridPlanner(base).plan(start, target.xy)
        return path is not None and len(path) >= 2
