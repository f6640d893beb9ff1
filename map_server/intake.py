"""Between Zenoh's ``delta/*`` subscriber and the map server's worker (map_server.server).

:class:`DeltaIntake` refuses an unknown or quarantined robot's payload, or an oversized one,
before reading it; queues the others in the :class:`~map_server.inbox.Inbox` (refused when
the robot's queue is full); admits each queued payload through
:class:`~map_server.admission.Admission`; and counts every refusal under its kind in the team
map and logs it (one line per kind per 10 s, with counts). Nothing here raises into Zenoh or
into the worker: whatever one payload raises is confined to it.
"""

from __future__ import annotations

import threading

import zenoh

from map_server.admission import Admission
from map_server.inbox import Inbox
from map_server.ledger import Rejected
from map_server.team_map import MergedMap
from swarm.log_limit import LogLimiter
from swarm.protocol.codec import short
from swarm.protocol.wire import DeltaMessage


class DeltaIntake:
    """The refusals, the queueing and the admission of the deltas of ``delta/<robot>``.

    ``lock`` is the server's map lock (held while a refusal is counted); ``max_payload`` is
    in bytes; ``peer_log`` rate-limits what a remote peer makes the server log."""

    def __init__(
        self,
        team: MergedMap,
        lock: threading.Lock,
        admission: Admission,
        inbox: Inbox,
        max_payload: int,
        peer_log: LogLimiter,
    ) -> None:
        self.team = team
        self.admission = admission
        self.max_payload = max_payload
        self._lock = lock
        self._inbox = inbox
        self._peer_log = peer_log

    def on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh's callback: refuse an unknown or quarantined robot or an oversized payload
        before reading it, else queue it (refused when the robot's queue is full). Never raises
        into Zenoh. (A quarantined robot's agent, never acked, resends its whole outbox every
        few seconds: hundreds of payloads a second that need not be copied or decoded.)"""
        try:
            robot = str(sample.key_expr).rsplit("/", 1)[-1]
            size = len(sample.payload)
            if not self.admission.accepts_robot(robot):
                self.reject(robot, None, Rejected("unknown_robot", self.admission.unknown_reason(robot)))
            elif robot in self.team.quarantined:  # checked again when applied (set at run time)
                self.reject(robot, None, Rejected("quarantined", f"{robot} is quarantined"))
            elif size > self.max_payload:
                reason = f"payload of {size:,} bytes over the maximum {self.max_payload:,}"
                self.reject(robot, None, Rejected("too_large", reason))
            elif not self._inbox.offer(robot, sample.payload.to_bytes(), _attachment(sample)):
                refused = self._inbox.refused[robot]
                self._peer_log.warning(
                    "inbox_full",
                    "inbox of %s full: payload refused (#%d; its agent resends it)",
                    robot,
                    refused,
                )
        except Exception:  # noqa: BLE001 (a callback must never raise into Zenoh)
            self._peer_log.exception("delta_callback", "delta callback failed")

    def reject(self, robot: str, msg: DeltaMessage | None, exc: Rejected) -> None:
        """Count a refused delta under its kind and log it (one line per kind per 10 s, with counts)."""
        with self._lock:
            count = self.team.count_rejected(exc.kind)
        ident = "" if msg is None else f" epoch {msg.epoch} seq {msg.seq}"
        self._peer_log.warning(
            f"rejected:{exc.kind}",
            "rejected delta on delta/%s%s (%s, #%d): %s",
            short(robot, 40),
            ident,
            exc.kind,
            count,
            exc,
        )

    def admit(self, robot: str, payload: bytes, mac: bytes | None) -> DeltaMessage | None:
        """The validated delta if it is new, else None (a duplicate, or refused and counted).
        Whatever one payload raises is confined to it."""
        try:
            return self.admission.admit(robot, payload, mac)
        except Rejected as exc:
            self.reject(robot, None, exc)
        except Exception as exc:  # noqa: BLE001 (one delta's failure must not touch the others)
            self._peer_log.exception(
                "admit_failure", "unexpected failure admitting a delta of %s", short(robot, 40)
            )
            self.reject(robot, None, Rejected("internal_error", f"{type(exc).__name__}: {short(exc)}"))
        return None


def _attachment(sample: zenoh.Sample) -> bytes | None:
    """The bytes attached to a sample (a delta's MAC), or None."""
    attachment = sample.attachment
    return None if attachment is None else attachment.to_bytes()
