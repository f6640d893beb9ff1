"""Server-issued epochs and the MAC of a delta (protocol v2; docs/protocol.md, "Epochs").

A robot asks the map server for an epoch with a Zenoh query on
``swarm/<mission>/map/epoch/<rid>`` (no payload). The reply (msgpack) is an
:class:`EpochGrant`: ``{"v": 2, "robot": rid, "epoch": E, "key": <16 bytes>}``. Every
``delta/<rid>`` sample of that epoch then carries, as its Zenoh attachment, the first 16
bytes of HMAC-SHA256(key, payload) over the exact payload bytes (:func:`delta_mac`). The key
never leaves the server and that robot: ``merged`` carries the payload, never the MAC.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import time
from dataclasses import dataclass
from typing import Any

import zenoh

from swarm.protocol import bus, codec, replies
from swarm.protocol.codec import WireError

log = logging.getLogger("swarm.protocol.epochs")

#: Bytes of an epoch's key and of a delta's MAC (HMAC-SHA256 truncated to its first 16 bytes).
KEY_BYTES = 16
MAC_BYTES = 16


def delta_mac(key: bytes, payload: bytes) -> bytes:
    """The attachment of a ``delta/<rid>`` sample: HMAC-SHA256(key, payload)[:16]."""
    return hmac.new(key, payload, hashlib.sha256).digest()[:MAC_BYTES]


def mac_matches(key: bytes, payload: bytes, mac: bytes | None) -> bool:
    """Whether ``mac`` is the MAC of ``payload`` under ``key`` (constant-time compare)."""
    return mac is not None and len(mac) == MAC_BYTES and hmac.compare_digest(delta_mac(key, payload), mac)


@dataclass(frozen=True)
class EpochGrant:
    """The ``map/epoch/<rid>`` reply: the epoch the server issued to ``robot`` and its MAC key."""

    robot: str
    epoch: int
    key: bytes

    KIND = "epoch"

    def encode(self) -> bytes:
        fields = {"robot": self.robot, "epoch": int(self.epoch), "key": bytes(self.key)}
        return codec.pack(self.KIND, fields, codec.DELTA_VERSION)

    @classmethod
    def decode(cls, payload: Any) -> EpochGrant:
        kind = cls.KIND
        msg = codec.unpack(payload, kind, (codec.DELTA_VERSION,))
        key = codec.require(msg, "key", kind)
        if not isinstance(key, bytes) or len(key) != KEY_BYTES:
            raise WireError(f"{kind}: key must be {KEY_BYTES} raw bytes")
        return cls(
            codec.text(codec.require(msg, "robot", kind), "robot", kind),
            codec.integer(codec.require(msg, "epoch", kind), "epoch", kind, 1),
            key,
        )

    def sign(self, payload: bytes) -> bytes:
        """The MAC to attach to ``payload`` (a delta of this epoch)."""
        return delta_mac(self.key, payload)


def ask_epoch(session: zenoh.Session, mission: str, robot: str, timeout: float = 2.0) -> EpochGrant | None:
    """Ask the map server for a new epoch of ``robot``; None when no server answers in time.

    Raises :class:`EpochRefused` for an error reply (unknown or quarantined robot) or a
    malformed grant, and ``replies.ConflictingReplies`` when repliers disagree.
    """
    selector = bus.key(mission, "map", "epoch", robot)
    answer = replies.ask(session, selector, timeout=timeout)
    if answer is None:
        return None
    if answer.ok is None:
        raise EpochRefused(answer.error or f"{selector}: error reply")
    try:
        grant = EpochGrant.decode(answer.ok)
    except WireError as exc:
        raise EpochRefused(f"{selector}: {exc}") from exc
    if grant.robot != robot:
        raise EpochRefused(f"{selector}: the grant names robot {codec.short(grant.robot, 40)}")
    return grant


def wait_for_epoch(
    session: zenoh.Session,
    mission: str,
    robot: str,
    timeout: float = 60.0,
    ask_timeout: float = 2.0,
) -> EpochGrant:
    """Ask until the server issues an epoch (for tools and tests: a bounded wait);
    ``TimeoutError`` after ``timeout`` s, :class:`EpochRefused` on a refusal."""
    deadline = time.monotonic() + timeout
    while True:
        grant = ask_epoch(session, mission, robot, ask_timeout)
        if grant is not None:
            return grant
        if time.monotonic() >= deadline:
            raise TimeoutError(f"no map server issued an epoch on {bus.key(mission, 'map', 'epoch', robot)}")
        time.sleep(0.2)


class EpochRefused(RuntimeError):
    """The map server answered ``map/epoch/<rid>`` with an error (its text says why)."""


def put_delta(publisher: zenoh.Publisher, grant: EpochGrant, payload: bytes) -> None:
    """Publish a delta payload of ``grant``'s epoch with its MAC as the attachment."""
    publisher.put(payload, attachment=grant.sign(payload))


class SigningPublisher:
    """A ``delta/<rid>`` publisher of a tool or bench: :meth:`renew` asks the server for an
    epoch, :meth:`put` attaches each payload's MAC under it (reliable, congestion control BLOCK)."""

    def __init__(self, session: zenoh.Session, mission: str, robot: str) -> None:
        self.session, self.mission, self.robot = session, mission, robot
        self.pub = bus.reliable_publisher(session, bus.key(mission, "delta", robot))
        self.grant: EpochGrant | None = None

    def renew(self, timeout: float = 30.0) -> int:
        """Ask for a new epoch (TimeoutError when no server issues one); returns it."""
        self.grant = wait_for_epoch(self.session, self.mission, self.robot, timeout)
        return self.grant.epoch

    @property
    def epoch(self) -> int | None:
        return None if self.grant is None else self.grant.epoch

    @property
    def matching_status(self):  # for bus.wait_for_subscribers
        return self.pub.matching_status

    def put(self, payload: bytes) -> None:
        if self.grant is None:
            raise RuntimeError(f"{self.robot}: no epoch yet (call renew first)")
        put_delta(self.pub, self.grant, payload)

    def undeclare(self) -> None:
        self.pub.undeclare()
