"""The map server's acknowledgements of one agent's deltas (``map/acks``; docs/protocol.md).

:class:`AckPoller` asks ``map/acks`` every :data:`ACK_POLL_S` seconds from its own thread,
lets the outbox and the sender forget what the server holds durably, and sends again the
deltas left unacked over :data:`RESEND_AFTER_S` seconds; at shutdown :meth:`AckPoller.await_all`
waits until the server holds every delta sent. Nothing is acked before the server has issued
the agent an epoch, and no answer (no server yet) keeps everything.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable

import zenoh

from robot_agent.delta_sender import DeltaSender
from robot_agent.sharing import DeltaOutbox
from swarm.map.delta import Delta
from swarm.protocol import replies

log = logging.getLogger("swarm.agent")

ACK_POLL_S = 2.0
RESEND_AFTER_S = 5.0


class AckPoller:
    """Polls ``acks_key`` for ``robot_id``'s last contiguous acked seq under ``epoch()``.

    ``publish(seq, delta)`` sends a delta again (never blocks). :attr:`acked` is the map
    server's last contiguous acked seq of this run's deltas (0 before any)."""

    def __init__(
        self,
        session: zenoh.Session,
        acks_key: str,
        robot_id: str,
        outbox: DeltaOutbox,
        sender: DeltaSender,
        epoch: Callable[[], int | None],
        publish: Callable[[int, Delta], None],
    ) -> None:
        self.session = session
        self.acks_key = acks_key
        self.robot_id = robot_id
        self.outbox = outbox
        self.sender = sender
        self._epoch = epoch
        self._publish = publish
        self.acked = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)

    def start(self) -> None:
        """Start polling from a daemon thread."""
        self._thread.start()

    def stop(self) -> None:
        """Stop polling and wait for the thread (at most one poll and its query)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=ACK_POLL_S + 1.5)

    def _poll(self) -> None:
        while not self._stop.wait(ACK_POLL_S):
            acks = self.query(timeout=1.0)
            if acks is None:
                continue  # no server yet: keep everything
            self._take(acks)
            self.sender.forget(acks)
            self._resend(RESEND_AFTER_S)

    def _take(self, acks: int) -> None:
        self.outbox.acknowledge(acks)
        self.acked = max(self.acked, acks)

    def _resend(self, after_s: float) -> None:
        """Send again the unacked deltas put over ``after_s`` s ago, oldest first (seq order)."""
        now = time.monotonic()
        for seq, delta in self.outbox.to_resend():
            if now - self.sender.last_sent(seq) > after_s:
                self.outbox.stats.resent += 1
                self._publish(seq, delta)

    def query(self, timeout: float = 1.0) -> int | None:
        """The agent's last contiguous acked seq per the map server, or None if none answers
        within ``timeout`` seconds (or several different ones answer, or no epoch yet)."""
        epoch = self._epoch()
        if epoch is None:
            return None  # nothing can be acked before the server issued an epoch
        try:
            answer = replies.ask(self.session, self.acks_key, timeout=timeout)
            if answer is None or answer.ok is None:
                return None
            acks = json.loads(answer.ok)
            return int(acks.get(self.robot_id, {}).get(str(epoch), 0))
        except replies.ConflictingReplies as exc:  # someone besides the server answers: trust none
            log.warning("acks refused: %s", exc)
        except (zenoh.ZError, ValueError, AttributeError) as exc:
            log.debug("acks query failed: %s", exc)
        return None

    def await_all(self, timeout: float) -> None:
        """Ask ``map/acks``, resending what is unacked, until all is acked, no server, or
        ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while self.acked < self.outbox.seq and (left := deadline - time.monotonic()) > 0:
            acks = self.query(timeout=min(1.0, left))
            if acks is None:
                return  # no map server answers: nothing to wait for
            self._take(acks)
            self._resend(1.0)
            if self.acked < self.outbox.seq:
                time.sleep(0.05)
