"""The teammates' statuses an agent follows (``robot/*/status``), for keeping out of their way.

Each agent publishes ``robot/<rid>/status`` every frame (``docs/protocol.md``); every other agent
of the mission takes the newest one of each robot between two of its frames and notes where
that robot was (:class:`swarm.navigation.teammates.Teammates`). Anyone on an open bus can
publish statuses: malformed ones, ones whose robot differs from their key, and keys beyond
MAX_WAITING_KEYS between two frames are refused and counted, the log lines bounded.
"""

from __future__ import annotations

import logging
import threading

import zenoh

from swarm.log_limit import LogLimiter
from swarm.navigation.teammates import Teammates
from swarm.protocol import bus
from swarm.protocol.robot_messages import status_on_key
from swarm.protocol.wire import WireError

log = logging.getLogger(__name__)

#: Status keys held between two frames at most (a team's own robots are far fewer).
MAX_WAITING_KEYS = 256


class TeammateStatuses:
    """The newest status of each robot received since the last frame, on ``session``."""

    def __init__(self, session: zenoh.Session, mission: str, robot_id: str, peer_log: LogLimiter) -> None:
        self.robot_id = robot_id
        self.rejected = 0  # malformed, on another robot's key, or beyond MAX_WAITING_KEYS
        self._peer_log = peer_log
        self._lock = threading.Lock()
        self._waiting: dict[str, bytes] = {}  # key -> newest payload since the last frame
        self._sub = bus.subscribe(session, bus.key_pattern(mission, "robot", "*", "status"), self._on_status)

    def _on_status(self, key: str, payload: bytes) -> None:
        with self._lock:
            if key in self._waiting or len(self._waiting) < MAX_WAITING_KEYS:
                self._waiting[key] = payload  # a newer status of the same robot replaces the older
                return
            self.rejected += 1
        self._peer_log.warning("status_dropped", "%s: status dropped (too many robots)", self.robot_id)

    def apply(self, teammates: Teammates, now: float) -> int:
        """Note in ``teammates`` the statuses received since the last call, at mission time
        ``now`` (s, this frame's); returns how many were kept (not this robot's own, not older
        than the one held, not from the future: ``Teammates.update``)."""
        with self._lock:
            waiting, self._waiting = self._waiting, {}
        kept = 0
        for key, payload in waiting.items():
            try:
                status = status_on_key(key, payload)
            except WireError as exc:
                self.rejected += 1
                log.debug("%s: rejected status on %s: %s", self.robot_id, key, exc)
                continue
            xyz = status.pose.xyz
            kept += teammates.update(status.robot, status.t, xyz[0], xyz[1], now)
        return kept

    def undeclare(self) -> None:
        self._sub.undeclare()
