"""Which deltas the map server takes, and the epochs it issues (docs/protocol.md, "Deltas",
"Epochs", "Limits").

:class:`Admission` decides for each ``delta/<rid>`` payload, in this order: the robot is one
the server takes; the payload decodes as a v2 delta of the mission's grid that carries some
information; its epoch is a live epoch the server issued to that robot (``unknown_epoch``,
``stale_epoch``); the sample's attachment is the MAC of the payload under that epoch's key
(``bad_mac``); it is not a duplicate (counted, harmless); its seq is the next one the epoch
expects (``seq_gap``); its information fits the robot's bucket on the server's clock
(``too_much_information``, a *breach*: after ``quarantine_after`` breaches the robot is
quarantined). It also answers ``map/epoch/<rid>`` queries (:meth:`on_epoch_query`).
Breaches are counted only after the MAC is checked, so a stranger cannot get a robot
quarantined by forging deltas in its name.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import Counter
from collections.abc import Callable

import zenoh

from map_server.epochs import EpochRegistry
from map_server.ledger import Rejected, validate_delta
from map_server.limits import InformationBound, InformationBucket
from map_server.team_map import MergedMap, delta_id
from swarm.log_limit import LogLimiter
from swarm.protocol.codec import short
from swarm.protocol.epochs import EpochGrant, mac_matches
from swarm.protocol.map_messages import PRIOR_SOURCE
from swarm.protocol.wire import DeltaMessage

log = logging.getLogger("swarm.server")

#: Breaches of the information budget after which a robot is quarantined by default.
QUARANTINE_AFTER = 3


class Admission:
    """The server's checks on deltas, and its epochs; see the module docstring."""

    def __init__(
        self,
        team: MergedMap,
        lock: threading.Lock,
        registry: EpochRegistry,
        *,
        robots: frozenset[str],
        takes_prior: bool,
        robot_pattern: str | None,
        max_pattern_robots: int,
        bounds: dict[str, InformationBound],
        quarantine_after: int,
        quarantine: Callable[[str], None],
        peer_log: LogLimiter,
    ) -> None:
        self.team = team
        self._lock = lock
        self.registry = registry
        self._issue_lock = threading.Lock()
        self.robots = robots
        self.takes_prior = takes_prior
        self._pattern = re.compile(robot_pattern) if robot_pattern else None
        self.max_pattern_robots = max_pattern_robots
        known = {*team.ledger.robots(), *team.contributions.by_robot}
        #: the ids the pattern admitted (those of the store's past too), at most max_pattern_robots
        self._by_pattern = {
            r for r in known - robots if self._pattern is not None and self._pattern.fullmatch(r)
        }
        self._by_pattern_lock = threading.Lock()
        self.bounds = bounds
        self._default_bound = max(bounds.values(), key=lambda b: b.per_frame, default=None)
        self._buckets: dict[str, InformationBucket] = {}
        self.quarantine_after = quarantine_after
        self._quarantine = quarantine
        self.breaches: Counter[str] = Counter()
        self.epochs_issued = 0
        self._peer_log = peer_log

    # -- who may send ----------------------------------------------------------------------
    def accepts_robot(self, robot: str) -> bool:
        """Whether ``delta/<robot>`` is taken: one of the mission's (or configured) robots, or a
        full match of the configured pattern while fewer than ``max_pattern_robots`` ids have
        matched it (each admitted id costs memory for good: on an open bus anyone could invent
        ids without end)."""
        if robot in self.robots or (robot == PRIOR_SOURCE and self.takes_prior):
            return True
        if self._pattern is None or self._pattern.fullmatch(robot) is None:
            return False
        with self._by_pattern_lock:
            if robot not in self._by_pattern:
                if len(self._by_pattern) >= self.max_pattern_robots:
                    return False
                self._by_pattern.add(robot)
            return True

    def unknown_reason(self, robot: str) -> str:
        if self._pattern is not None and self._pattern.fullmatch(robot):
            return f"--robot-pattern has admitted its {self.max_pattern_robots} robots already"
        return "not one of the mission's robots"

    # -- deltas ----------------------------------------------------------------------------
    def admit(self, robot: str, payload: bytes, mac: bytes | None) -> DeltaMessage:
        """The validated delta, pending in the team map; None for a duplicate (counted). Raises
        Rejected (see the module docstring for the order of the checks)."""
        prior = robot == PRIOR_SOURCE and robot not in self.robots
        msg = validate_delta(payload, self.team.grid, robot, increments=not prior)
        if not msg.carries_information():  # no agent sends one: a flood would cost every replica
            raise Rejected("no_information", f"delta of {len(msg.idx)} voxels that changes nothing")
        if robot in self.team.quarantined:
            raise Rejected("quarantined", f"{robot} is quarantined")
        key = self.registry.key_of(robot, msg.epoch)
        if key is None:
            raise Rejected(*self.registry.refusal(robot, msg.epoch))
        if not mac_matches(key, payload, mac):
            what = "no MAC attached" if mac is None else f"a {len(mac)}-byte attachment that is not its MAC"
            raise Rejected("bad_mac", f"delta epoch {msg.epoch} seq {msg.seq} of {robot}: {what}")
        bound = None if prior else self.bounds.get(robot, self._default_bound)
        with self._lock:
            if self.team.is_known(delta_id(msg)):
                self.team.admit(msg)  # counts the duplicate
                return None
            expected = self.team.next_seq(robot, msg.epoch)
            if msg.seq != expected:
                raise Rejected(
                    "seq_gap", f"seq {msg.seq} of epoch {msg.epoch}: the next one taken is {expected}"
                )
            information = float(msg.dlam.sum(dtype="float64"))
            why = None if bound is None else self._bucket(robot, bound).refusal(information, time.monotonic())
            if why is None:
                self.team.admit(msg)  # map_overflow, mean_outside_unit: nothing charged
                if bound is not None:
                    self._buckets[robot].charge(information)
                return msg
            self.breaches[robot] += 1
            breaches = self.breaches[robot]
        why = f"delta of {robot}: {why} (breach {breaches} of {self.quarantine_after})"
        if 0 < self.quarantine_after <= breaches and robot not in self.team.quarantined:
            self._quarantine(robot)  # outside the lock: it rebuilds the map under it
            why += ": quarantined"
        raise Rejected("too_much_information", why)

    def _bucket(self, robot: str, bound: InformationBound) -> InformationBucket:
        bucket = self._buckets.get(robot)
        if bucket is None:
            bucket = self._buckets[robot] = InformationBucket(bound, time.monotonic())
        return bucket

    def release(self, msg: DeltaMessage) -> None:
        """Forget an admitted delta that could not be made durable or applied; its information
        goes back to its robot's bucket. Call with the server's lock held."""
        information = self.team.release(msg)
        bucket = self._buckets.get(msg.robot)
        if bucket is not None and information:
            bucket.refund(information)

    def applied(self, msg: DeltaMessage) -> None:
        """A delta was applied: its epoch is the robot's most recently active."""
        self.registry.touch(msg.robot, msg.epoch)

    # -- epochs ----------------------------------------------------------------------------
    def issue(self, robot: str) -> EpochGrant:
        """A new epoch of ``robot``, durable on return (OSError when the store cannot write);
        the epochs it fences leave the ledger (their deltas stay in the map)."""
        with self._issue_lock:  # one issue at a time; the worker reads on meanwhile (not its fsync)
            epoch, key, fenced = self.registry.issue(robot)
            with self._lock:
                for old in fenced:
                    self.team.ledger.drop(robot, old)
                self.epochs_issued += 1
        if fenced:
            log.info("%s: epoch %d issued; fenced %s", short(robot, 40), epoch, fenced)
        return EpochGrant(robot, epoch, key)

    def on_epoch_query(self, query: zenoh.Query) -> None:
        """``map/epoch/<rid>``: issue an epoch and answer the grant (msgpack), or an error reply."""
        robot = str(query.key_expr).rsplit("/", 1)[-1]
        if not self.accepts_robot(robot):
            query.reply_err(f"map/epoch: {short(robot, 40)} is {self.unknown_reason(robot)}".encode())
            return
        if robot in self.team.quarantined:
            query.reply_err(f"map/epoch: {short(robot, 40)} is quarantined".encode())
            return
        try:
            grant = self.issue(robot)
        except OSError as exc:
            self._peer_log.warning("epoch_store", "cannot issue an epoch of %s: %s", short(robot, 40), exc)
            query.reply_err(f"map/epoch: the store cannot write ({short(exc, 80)}); ask again".encode())
            return
        query.reply(query.key_expr, grant.encode())

    def acks(self) -> dict[str, dict[int, int]]:
        """``map/acks``: per robot, the contiguous ack of every epoch the ledger holds and 0 for
        a live epoch that has no delta yet. Call with the server's lock held."""
        acks = self.team.acks()
        for robot, epochs in self.registry.live().items():
            for epoch in epochs:
                acks.setdefault(robot, {}).setdefault(epoch, 0)
        return acks
