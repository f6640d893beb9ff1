"""The agent's delta publisher, off its frame-and-command loop (docs/protocol.md, "Epochs").

The loop hands each delta over with :meth:`DeltaSender.send`, which never blocks. A thread
of its own asks the map server for the robot's epoch (``map/epoch/<rid>``, again every 2 s
until one answers, with a progress line every 10 s), then encodes each delta as protocol v2
under that epoch and puts it on ``delta/<rid>`` with its MAC attached. A put that blocks (a
link that stops draining: congestion control BLOCK waits until Zenoh gives up on the link)
holds this thread only; the robot keeps fusing frames and answering commands, and its
outbox keeps every delta until the server acks it. Without a map server the agent maps
alone and keeps asking; the deltas wait here and go out, seqs 1, 2, ..., once it has an epoch.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable

import zenoh

from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.protocol import bus, replies
from swarm.protocol.epochs import EpochGrant, EpochRefused, ask_epoch
from swarm.protocol.wire import DeltaMessage

log = logging.getLogger("swarm.agent")

EPOCH_ASK_TIMEOUT_S = 2.0
EPOCH_RETRY_S = 2.0
WAITING_LINE_EVERY_S = 10.0


class DeltaSender:
    """Publishes ``(seq, t, delta)`` hand-overs of one robot on ``delta/<rid>`` from its own thread."""

    def __init__(
        self,
        session: zenoh.Session,
        mission: str,
        robot: str,
        grid: Grid,
        on_sent: Callable[[int, int], None] | None = None,
        on_epoch: Callable[[EpochGrant], None] | None = None,
    ) -> None:
        """``on_sent(seq, bytes)`` after each put; ``on_epoch(grant)`` once the server issued one."""
        self.session = session
        self.mission = mission
        self.robot = robot
        self.grid = grid
        self._on_sent = on_sent
        self._on_epoch = on_epoch
        self._pub = bus.reliable_publisher(session, bus.key(mission, "delta", robot))
        self._queue: queue.Queue[tuple[int, float, Delta]] = queue.Queue()
        self._lock = threading.Lock()
        self._queued: set[int] = set()  # handed over, not yet put
        self._sent_at: dict[int, float] = {}  # seq -> monotonic time of its latest put
        self._idle = threading.Condition(self._lock)
        self._stop = threading.Event()
        self.grant: EpochGrant | None = None
        self._thread = threading.Thread(target=self._run, name=f"{robot}-delta-sender", daemon=True)

    def start(self) -> None:
        self._thread.start()

    # -- what the loop and the acker call --------------------------------------------------
    def send(self, seq: int, t: float, delta: Delta) -> bool:
        """Hand a delta over (never blocks); False when that seq waits to be sent already."""
        with self._lock:
            if seq in self._queued:
                return False
            self._queued.add(seq)
        self._queue.put((seq, t, delta))
        return True

    def last_sent(self, seq: int) -> float:
        """Monotonic time of ``seq``'s latest put (0.0 if never put); +inf while it waits here."""
        with self._lock:
            if seq in self._queued:
                return float("inf")
            return self._sent_at.get(seq, 0.0)

    def forget(self, upto: int) -> None:
        """Drop the put times of seqs up to ``upto`` (acked)."""
        with self._lock:
            for seq in [s for s in self._sent_at if s <= upto]:
                del self._sent_at[seq]

    @property
    def epoch(self) -> int | None:
        return None if self.grant is None else self.grant.epoch

    def drain(self, timeout: float) -> bool:
        """Wait until every handed-over delta is put (True), or ``timeout`` s (False); False at
        once without an epoch (no server issued one: the deltas stay in the outbox)."""
        if self.grant is None:
            return not self._queued
        deadline = time.monotonic() + timeout
        with self._idle:
            while self._queued:
                left = deadline - time.monotonic()
                if left <= 0 or not self._idle.wait(left):
                    return not self._queued
        return True

    def stop(self) -> None:
        """Stop the thread (a put blocked on a dead link is left to the daemon thread)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)

    # -- the thread ------------------------------------------------------------------------
    def _run(self) -> None:
        self._wait_for_epoch()
        while not self._stop.is_set():
            try:
                seq, t, delta = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                self._put(seq, t, delta)
            except Exception:  # noqa: BLE001 (a failed put is resent after the ack poll)
                log.exception("%s: publishing delta %d failed", self.robot, seq)
            finally:
                with self._idle:
                    self._queued.discard(seq)
                    self._idle.notify_all()

    def _put(self, seq: int, t: float, delta: Delta) -> None:
        grant = self.grant
        msg = DeltaMessage(self.robot, grant.epoch, seq, t, self.grid, delta.idx, delta.dlam, delta.deta)
        payload = msg.encode()
        self._pub.put(payload, attachment=grant.sign(payload))
        with self._lock:
            self._sent_at[seq] = time.monotonic()
        if self._on_sent is not None:
            self._on_sent(seq, len(payload))

    def _wait_for_epoch(self) -> None:
        """Ask ``map/epoch/<rid>`` until a server issues one (or the sender stops)."""
        key = bus.key(self.mission, "map", "epoch", self.robot)
        started = last_line = time.monotonic()
        log.info("%s: waiting for the map server to issue an epoch (%s)...", self.robot, key)
        while not self._stop.is_set():
            why = "no answer"
            try:
                grant = ask_epoch(self.session, self.mission, self.robot, EPOCH_ASK_TIMEOUT_S)
                if grant is not None:
                    self.grant = grant
                    if self._on_epoch is not None:
                        self._on_epoch(grant)
                    log.info("%s: epoch %d issued by the map server", self.robot, grant.epoch)
                    return
            except (EpochRefused, replies.ConflictingReplies, zenoh.ZError) as exc:
                why = str(exc)
            now = time.monotonic()
            if now - last_line >= WAITING_LINE_EVERY_S:
                last_line = now
                log.info(
                    "%s: still waiting for an epoch on %s after %.0f s (%s); mapping on, %d deltas held",
                    self.robot,
                    key,
                    now - started,
                    why,
                    self._queue.qsize(),
                )
            self._stop.wait(EPOCH_RETRY_S)
