"""The teammates' statuses an agent follows (``robot/*/status``), for keeping out of their way.

Each agent publishes ``robot/<rid>/status`` every frame (``docs/protocol.md``); every other agent
of the mission takes the newest one of each robot between two of its frames and notes where
that robot was (:class:`swarm.navigation.teammates.Teammates`). Anyone on an open bus can
publish statuses: malformed ones, ones whose robot differs from their key, and keys beyond
MAX_WAITING_KEYS between two frames are refused and counted, the log lines bounded. The
statuses wait in a :class:`swarm.protocol.mailbox.Mailbox` (the newest of each key).
"""

from __future__ import annotations

import logging

import zenoh

from swarm.log_limit import LogLimiter
from swarm.navigation.teammates import Teammates
from swarm.protocol import bus
from swarm.protocol.mailbox import Mailbox
from swarm.protocol.robot_messages import status_on_key
from swarm.protocol.wire import WireError

log = logging.getLogger(__name__)

#: Status keys held between two frames at most (a team's own robots are far fewer).
MAX_WAITING_KEYS = 256


class TeammateStatuses:
    """The newest status of each robot received since the last frame, on ``session``."""

    def __init__(self, session: zenoh.Session, mission: str, robot_id: str, peer_log: LogLimiter) -> None:
        self.robot_id = robot_id
        self._malformed = 0  # malformed, or on another robot's key
        self._peer_log = peer_log
        #: status key -> the newest payload since the last frame
        self._waiting: Mailbox[str, bytes] = Mailbox(MAX_WAITING_KEYS)
        self._sub = bus.subscribe(session, bus.key_pattern(mission, "robot", "*", "status"), self._on_status)

    @property
    def rejected(self) -> int:
        """Statuses refused: malformed, on another robot's key, or beyond MAX_WAITING_KEYS."""
        return self._malformed + self._waiting.dropped

    def _on_status(self, key: str, payload: bytes) -> None:
        if self._waiting.put(key, payload).accepted:  # a newer status of a robot replaces the older
            return
        self._peer_log.warning("status_dropped", "%s: status dropped (too many robots)", self.robot_id)

    def apply(self, teammates: Teammates, now: float) -> int:
        """Note in ``teammates`` the statuses received since the last call, at mission time
        ``now`` (s, this frame's); returns how many were kept (not this robot's own, not older
        than the one held, not from the future: ``Teammates.update``)."""
        kept = 0
        for key, payload in self._waiting.take_all().items():
            try:
                status = status_on_key(key, payload)
            except WireError as exc:
                self._malformed += 1
                log.debug("%s: rejected status on %s: %s", self.robot_id, key, exc)
                continue
            xyz = status.pose.xyz
            kept += teammates.update(status.robot, status.t, xyz[0], xyz[1], now)
        return kept

    def undeclare(self) -> None:
        self._sub.undeclare()
