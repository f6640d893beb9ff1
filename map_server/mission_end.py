"""When the mission is done, as the map server sees it, and telling everyone (``mission/done``).

The map server holds the whole team map, so it decides: the mission is done once the team
map's entropy is at or below the mission's H_th (eq. 36: ``threshold``), or once every robot
still heard from says it has nothing left (its ``robot/<rid>/status`` state is ``done``; a
robot silent for :data:`STALE_STATUS_S` s no longer counts, so a team started with fewer
robots than the mission lists ends too: ``nothing left``). :class:`MissionEnd` follows the
statuses, is asked by the server's loop (:meth:`MissionEnd.check`), puts
:class:`~swarm.protocol.mission_messages.MissionDone` on ``mission/done`` when it is first
done and every :data:`REPEAT_S` s after, and logs one summary line.

A sharded map service (docs/sharding.md) has one decider, shard 0, on the mission's own prefix
(``mission/done``, ``robot/<rid>/status``); the stats it is given are the team's
(map_server.shard_peers: the entropy summed over the shards), and while a shard is unknown
(``shards_unknown``) the threshold does not end the mission.
"""

from __future__ import annotations

import logging
import threading
import time

import zenoh

from swarm.log_limit import LogLimiter
from swarm.protocol import bus
from swarm.protocol.mission_messages import MissionDone
from swarm.protocol.wire import WireError, status_on_key

log = logging.getLogger("swarm.server")

#: A robot whose last status is older than this (s, wall clock) no longer counts for "nothing left".
STALE_STATUS_S = 30.0
#: Seconds between repeats of ``mission/done`` (for processes that join or reconnect later).
REPEAT_S = 2.0


class MissionEnd:
    """Decides and announces the end of ``mission`` on ``session`` (see the module doc)."""

    def __init__(
        self, session: zenoh.Session, mission: str, robots: frozenset[str], threshold_bits: float | None
    ) -> None:
        """``threshold_bits``: H_th, or None for a mission that ends only with "nothing left"."""
        self.mission = mission
        self.robots = robots
        self.threshold_bits = threshold_bits
        self.done: MissionDone | None = None
        self._states: dict[str, tuple[str, float]] = {}  # robot -> (state, monotonic time heard)
        self._lock = threading.Lock()
        self._last_put = -REPEAT_S
        self._peer_log = LogLimiter(log)
        self._pub = bus.reliable_publisher(session, bus.key(mission, "mission", "done"))
        self._sub = bus.subscribe(session, bus.key_pattern(mission, "robot", "*", "status"), self._on_status)

    def _on_status(self, key: str, payload: bytes) -> None:
        try:
            status = status_on_key(key, payload)
        except WireError as exc:
            self._peer_log.warning("status", "ignored a robot status: %s", exc)
            return
        if status.robot in self.robots:
            with self._lock:
                self._states[status.robot] = (status.state, time.monotonic())

    def robots_done(self, now: float | None = None) -> tuple[list[str], list[str]]:
        """(robots heard from within STALE_STATUS_S whose state is done, those whose is not)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            live = {r: s for r, (s, heard) in self._states.items() if now - heard <= STALE_STATUS_S}
        done = sorted(r for r, s in live.items() if s == "done")
        return done, sorted(set(live) - set(done))

    def check(self, stats: dict) -> MissionDone | None:
        """Called with the server's ``map/stats`` (sharded: the team's, with ``shards_unknown``)
        every half second or so: decide, and put ``mission/done`` when done (again every
        REPEAT_S s). Returns the end once it came."""
        if self.done is None:
            done, busy = self.robots_done()
            entropy = float(stats.get("entropy_bits", float("inf")))
            complete = not stats.get("shards_unknown")  # every shard's entropy is in the sum
            if self.threshold_bits is not None and complete and entropy <= self.threshold_bits:
                reason = "threshold"
            elif done and not busy:
                reason = "nothing left"
            else:
                return None
            self.done = MissionDone(
                reason, time.time(), entropy, self.threshold_bits, float(stats.get("known_fraction", 0.0)),
                int(stats.get("deltas_applied", 0)), done,
            )  # fmt: skip
            log.info(
                "mission done (%s); the map server goes on answering queries until it is stopped "
                "(e.g. swarm map picture --connect ... --out DIR)",
                self.done.describe(),
            )
        now = time.monotonic()
        if now - self._last_put >= REPEAT_S:
            self._last_put = now
            self._pub.put(self.done.encode())
        return self.done

    def close(self) -> None:
        self._sub.undeclare()
        self._pub.undeclare()
