"""What the agent asks the coordinator before its explorer chooses a target (``coord/assign``).

:class:`AssignmentRequests` turns the coordinator's reply into the :class:`TeamAdvice` the
explorer decides with: the coordinator's target for this robot, or none (choose alone,
eq. 35) with, after "nothing left", where the teammates went to look and where they head.
After a silence of :data:`COORDINATOR_TIMEOUT_S` seconds the robot chooses alone for
:data:`COORDINATOR_RETRY_S` seconds before asking again. The answers are counted
(``silent``, ``nothing_left``, ``assigned``, ``flushed``).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable

import numpy as np
import zenoh

from robot_agent.decision import TeamAdvice
from swarm.navigation.exploration import ExplorationTarget
from swarm.protocol.coord_client import ask_for_target
from swarm.protocol.wire import Pose

COORDINATOR_TIMEOUT_S = 1.0  # wait this long for coord/assign before choosing alone
COORDINATOR_RETRY_S = 10.0  # after a silence, choose alone this long before asking again


class AssignmentRequests:
    """Asks ``coord/assign`` of ``mission`` for ``robot``; ``flush()`` shares at once every
    pending voxel (a reply's "flush on demand": the coordinator lacks what this robot saw)."""

    def __init__(self, session: zenoh.Session, mission: str, robot: str, flush: Callable[[], None]) -> None:
        self.session = session
        self.mission = mission
        self.robot = robot
        self._flush = flush
        self.counts: Counter[str] = Counter()
        self._quiet_until = 0.0

    def advice(self, pose: Pose | None) -> TeamAdvice:
        """What the coordinator says for a robot at ``pose`` (None: no frame yet, choose alone)."""
        now = time.monotonic()
        alone = TeamAdvice()  # only a "nothing left" reply says where the others head
        if pose is None or now < self._quiet_until:
            return alone
        reply = ask_for_target(self.session, self.mission, self.robot, pose, COORDINATOR_TIMEOUT_S)
        if reply is None:
            self.counts["silent"] += 1
            self._quiet_until = now + COORDINATOR_RETRY_S
            return alone
        if reply.target is None:
            self.counts["nothing_left"] += 1
            # choosing alone now: not the columns the teammates went to look at
            views = [np.array(v, dtype=np.float64) for v in reply.views]
            return TeamAdvice(None, views, [np.array(g, dtype=np.float64) for g in reply.goals])
        self.counts["assigned"] += 1
        if reply.flush:  # flush on demand: the coordinator lacks what this robot saw there
            self.counts["flushed"] += 1
            self._flush()
        gaze = reply.gaze or (1.0, 0.0, 0.0)
        xy = np.array(reply.target[:2], dtype=np.float64)
        return TeamAdvice(
            ExplorationTarget(xy, math.atan2(gaze[1], gaze[0]), reply.utility, None, "assigned")
        )
