"""What a robot's explorer decides each frame, the states it is in, and the team's advice the
agent passes in before it decides."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from swarm.navigation.targets import ExplorationTarget


class ExplorerState(StrEnum):
    """Where the explorer's loop stands (docs/design.md section 3); the value is the name a
    status and a decision carry."""

    LOOK_AROUND = "look_around"  # turning once on the spot
    CHOOSE = "choose"  # choosing the next target (the fallback ladder)
    DRIVE = "drive"  # following the path to the target
    GAZE = "gaze"  # turning to the target's gaze on arrival
    LOOK_UP = "look_up"  # one frame seen with the tilt head raised, after a gaze
    DONE = "done"  # H below H_th, or nothing reachable is informative


@dataclass
class Decision:
    """What the robot does this frame: speed ``v`` (m/s), turn rate ``omega`` (rad/s), the state
    it reports (an ExplorerState's value, or ``"wait"`` for a teammate), its target (x, y; m)
    and the camera head's tilt (rad, positive down; None: no tilt head)."""

    v: float
    omega: float
    state: str
    target: tuple[float, float] | None = None
    tilt: float | None = None


@dataclass(frozen=True)
class TeamAdvice:
    """What the coordinator said before this decision (the agent asks, the explorer decides).

    ``target``: the coordinator's target for this robot (kind ``"assigned"``); None: choose
    alone. ``views``: x-y of the columns the teammates went to look at (a "nothing left" reply;
    None: not told this time, keep the last ones). ``goals``: x-y of where the teammates head
    (only a "nothing left" reply says; empty otherwise)."""

    target: ExplorationTarget | None = None
    views: list[np.ndarray] | None = None
    goals: list[np.ndarray] = field(default_factory=list)
