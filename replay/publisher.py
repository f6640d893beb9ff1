"""Publish recorded frames on ``robot/<id>/frame`` as a robot driver would.

Lockstep (default): each frame waits for the agent's ``robot/<id>/cmd`` answering its seq,
so no frame is lost whatever the agent's speed. ``realtime``: frames leave at the recorded
rate whatever the agent does (as on a robot); at the end the publisher waits for the answer
to the last frame, and each frame's round trip is then taken from the answers' arrival times
(an agent that falls behind answers late: its lag is in the round trip).
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import zenoh

from swarm.protocol import bus
from swarm.protocol.wire import Cmd, Frame, WireError


@dataclass
class PublishLog:
    """Per frame: seq, recording time (s), round trip to the agent's answer (s; None: none), and
    when it left (s after the first frame left, wall clock)."""

    rows: list[tuple[int, float, float | None]] = field(default_factory=list)
    sent_s: list[float] = field(default_factory=list)
    unanswered: int = 0


class FramePublisher:
    """Sends frames of one robot and waits for the agent's answers."""

    def __init__(self, session: zenoh.Session, mission: str, robot: str) -> None:
        self.robot = robot
        self._pub = bus.reliable_publisher(session, bus.key(mission, "robot", robot, "frame"))
        self._cmds: queue.Queue = queue.Queue()
        self._sub = bus.subscribe(  # (arrival time, payload): realtime round trips come from it
            session,
            bus.key(mission, "robot", robot, "cmd"),
            lambda _k, p: self._cmds.put((time.perf_counter(), p)),
        )

    def wait_for_agent(self, timeout: float) -> bool:
        """True once an agent subscribes to this robot's frames."""
        return bus.wait_for_subscribers([self._pub], timeout)

    def send(self, frame: Frame, timeout: float | None) -> float | None:
        """Publish a frame; with a timeout, wait for its cmd and return the round trip (s)."""
        start = time.perf_counter()
        self._pub.put(frame.encode())
        if timeout is None:
            return None
        answered = self._await_answer(frame.seq, timeout)
        return None if answered is None else answered - start

    def _await_answer(
        self, seq: int, timeout: float, arrivals: dict[int, float] | None = None
    ) -> float | None:
        """perf_counter time at which the cmd answering ``seq`` arrived (None: not within ``timeout`` s);
        the other answers met on the way go into ``arrivals``."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                arrived, payload = self._cmds.get(timeout=left)
            except queue.Empty:
                break
            try:
                cmd = Cmd.decode(payload)
            except WireError:
                continue
            if cmd.seq == seq:
                return arrived
            if arrivals is not None:
                arrivals.setdefault(cmd.seq, arrived)
        return None

    def run(
        self,
        frames: Iterable[Frame],
        realtime: bool = False,
        timeout: float = 60.0,
        after_each: Callable[[Frame, float | None], None] | None = None,
    ) -> PublishLog:
        """Send every frame (lockstep, or paced by the recorded times with ``realtime``).

        ``after_each(frame, round_trip_s)`` runs after each frame (round trip None in realtime,
        where it is known only at the end: see ``PublishLog.rows``)."""
        log = PublishLog()
        t0_rec = t0_wall = None
        sent_at: list[float] = []
        for frame in frames:
            # One clock for pacing and for the log, and the first frame's send time as the origin:
            # a frame can then never leave before its recorded offset, however late the first went.
            now = time.perf_counter()
            if realtime:
                if t0_rec is None:
                    t0_rec, t0_wall = frame.t, now
                wait = (frame.t - t0_rec) - (now - t0_wall)
                while wait > 0:
                    time.sleep(wait)
                    now = time.perf_counter()
                    wait = (frame.t - t0_rec) - (now - t0_wall)
            sent_at.append(now)
            rtt = self.send(frame, None if realtime else timeout)
            if rtt is None and not realtime:
                log.unanswered += 1
            log.rows.append((frame.seq, frame.t, rtt))
            if after_each is not None:
                after_each(frame, rtt)
        log.sent_s = [t - sent_at[0] for t in sent_at]
        if realtime and log.rows:
            arrivals: dict[int, float] = {}
            last = self._await_answer(log.rows[-1][0], timeout, arrivals)
            if last is not None:
                arrivals[log.rows[-1][0]] = last
            log.rows = [(seq, t, arrivals[seq] - sent if seq in arrivals else None)
                        for (seq, t, _), sent in zip(log.rows, sent_at, strict=True)]  # fmt: skip
            log.unanswered = sum(rtt is None for _, _, rtt in log.rows)
        return log

    def close(self) -> None:
        self._sub.undeclare()
        self._pub.undeclare()
